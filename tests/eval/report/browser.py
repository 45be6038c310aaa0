"""Open a report page in headless Chromium and say what a person would see (for the tests)."""
from __future__ import annotations

import base64
import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tests.eval.report.cdp import Browser


@dataclass
class PageCheck:
    """What the browser saw: rendered plots, element ids, console errors, requests, screenshot."""

    expected: int
    rendered: int
    failed: list[str]
    ids: list[str]
    plots: dict[str, dict[str, Any]]
    console_errors: list[str] = field(default_factory=list)
    requests: list[str] = field(default_factory=list)
    screenshot: bytes = b""
    height_px: int = 0


_PROBE = """(() => {
  const plots = {};
  for (const el of document.querySelectorAll(".plot")) {
    plots[el.id] = {plotly: el.classList.contains("js-plotly-plot"), svg: el.querySelectorAll("svg.main-svg").length,
                    canvas: el.querySelectorAll("canvas").length, traces: (el.data || []).length,
                    width: el.getBoundingClientRect().width, height: el.getBoundingClientRect().height};
  }
  return JSON.stringify({expected: +document.body.dataset.figuresExpected,
                         rendered: +document.body.dataset.figuresRendered,
                         failed: window.poseidonReport ? window.poseidonReport.failed : ["no poseidonReport"],
                         ids: Array.from(document.querySelectorAll("[id]")).map(e => e.id), plots: plots,
                         height: document.documentElement.scrollHeight});
})()"""


def _console_errors(events: list[dict[str, Any]]) -> list[str]:
    out = []
    for e in events:
        m, p = e["method"], e.get("params", {})
        if m == "Runtime.exceptionThrown":
            d = p.get("exceptionDetails", {})
            out.append("exception: " + str(d.get("exception", {}).get("description") or d.get("text")))
        elif m == "Runtime.consoleAPICalled" and p.get("type") in ("error", "assert"):
            out.append("console." + p["type"] + ": " + " ".join(str(a.get("value", a.get("description")))
                                                               for a in p.get("args", [])))
        elif m == "Log.entryAdded" and p.get("entry", {}).get("level") == "error":
            out.append("log: " + p["entry"].get("text", ""))
    return out


def check_page(page: Path, workdir: Path, width: int = 1400, height: int = 1000, timeout_s: float = 90.0) -> PageCheck:
    """Load ``page`` (a file), wait until every plot has rendered, probe the DOM, screenshot it."""
    with Browser(workdir / "chromium-profile") as b:
        target = b.call("Target.createTarget", {"url": "about:blank"})
        s = b.call("Target.attachToTarget", {"targetId": target["targetId"], "flatten": True})["sessionId"]
        for method in ("Page.enable", "Runtime.enable", "Log.enable", "Network.enable"):
            b.call(method, session=s)
        b.call("Emulation.setDeviceMetricsOverride", {"width": width, "height": height, "deviceScaleFactor": 1,
                                                      "mobile": False}, session=s)
        b.call("Page.navigate", {"url": page.resolve().as_uri()}, session=s)
        deadline = time.monotonic() + timeout_s
        state: dict[str, Any] = {}
        while time.monotonic() < deadline:
            r = b.call("Runtime.evaluate", {"expression": _PROBE, "returnByValue": True}, session=s)
            value = r.get("result", {}).get("value")
            if value:
                state = json.loads(value)
                if state["expected"] and state["rendered"] >= state["expected"]:
                    break
            b.pump(0.5)
        b.pump(1.0)  # late console messages
        shot = b.call("Page.captureScreenshot", {"format": "png", "captureBeyondViewport": True}, session=s,
                      timeout_s=60)
        requests = [e["params"]["request"]["url"] for e in b.events if e["method"] == "Network.requestWillBeSent"]
        return PageCheck(expected=state.get("expected", 0), rendered=state.get("rendered", 0),
                         failed=state.get("failed", []), ids=state.get("ids", []), plots=state.get("plots", {}),
                         console_errors=_console_errors(b.events), requests=requests,
                         screenshot=base64.b64decode(shot["data"]), height_px=state.get("height", 0))
