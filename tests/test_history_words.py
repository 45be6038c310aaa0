"""No work history in the project's text: no round, issue or work-session numbering, no machine paths.

The code and the docs say what the system does and what was measured, not when or in which
round of work (``docs/DECISIONS.md`` keeps the measurements by topic).  Every tracked text file
(``git ls-files``: ``.py``, ``.md``, ``.yaml``, ``.toml``, ``.sh``, ``.txt``, ``.cfg`` and
``.ci/run``) is scanned line by line for the patterns of :data:`PATTERNS`; a failure lists each
hit as ``file:line: text``.

"Session" is also a word of the domain: a map continued over several missions has sessions
("session 1", "the first session's experiences", "a session break edge", "an earlier session",
"one session", "the same session").  So only the phrases that cannot name a map session are
history: ordinals from "fourth" on (``poseidon`` maps in the docs and tests have two or three
sessions), a numeral ordinal from 4th on, "this / last / previous / next session" and
"sessions ago".  "Round" is history only with a number after it (``--rounds 2``, a benchmark
option, and "interleaved rounds" are not).

Paths of the machine the work ran on (``/work/...``, ``/root/...``) and scratch folders under
``/tmp`` (``/tmp/<name>/...``) are not the project's; a single file or folder under ``/tmp``
(a product's default cache such as ``/tmp/poseidon-numba-cache``) is allowed.
"""
from __future__ import annotations

import re
import subprocess
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SUFFIXES = {".py", ".md", ".yaml", ".toml", ".sh", ".txt", ".cfg"}
EXTRA_FILES = {".ci/run"}
SELF = Path(__file__).resolve().relative_to(REPO).as_posix()

_ORDINALS = ("fourth|fifth|sixth|seventh|eighth|ninth|tenth|eleventh|twelfth|thirteenth|"
             "fourteenth|fifteenth|sixteenth|seventeenth|eighteenth|nineteenth|twentieth|"
             "twenty-\\w+|thirtieth")

#: name -> pattern (case-insensitive) of a work-history phrase.
PATTERNS: dict[str, re.Pattern[str]] = {
    "round number": re.compile(r"(?<![-\w])rounds? #?\d+", re.IGNORECASE),
    "issue number": re.compile(r"\bissues? #?\d+", re.IGNORECASE),
    "ordinal work session": re.compile(rf"\b(?:{_ORDINALS})[- ]sessions?\b", re.IGNORECASE),
    "numbered work session": re.compile(r"\b(?:[4-9]|\d{2,})(?:st|nd|rd|th)[- ]sessions?\b", re.IGNORECASE),
    "relative work session": re.compile(r"\b(?:this|last|previous|next)[- ]session\b|\bsessions? ago\b",
                                        re.IGNORECASE),
    "machine path": re.compile(r"(?<![\w.~-])/(?:work|root)/"),
    "scratch path": re.compile(r"(?<![\w.~-])/tmp/[^\s/'\"`)]+/"),
}


def tracked_text_files(root: Path = REPO) -> list[str]:
    """The tracked files of ``root`` whose suffix is in :data:`SUFFIXES`, plus :data:`EXTRA_FILES`."""
    out = subprocess.run(["git", "ls-files", "-z"], cwd=root, capture_output=True, check=True).stdout
    names = [n for n in out.decode().split("\0") if n]
    return sorted(n for n in names if Path(n).suffix in SUFFIXES or n in EXTRA_FILES)


def history_hits(text: str) -> list[tuple[int, str, str]]:
    """``(line number, pattern name, line)`` for every line of ``text`` that matches a pattern."""
    hits = []
    for no, line in enumerate(text.splitlines(), 1):
        for name, pattern in PATTERNS.items():
            if pattern.search(line):
                hits.append((no, name, line.strip()))
    return hits


def test_the_patterns_catch_history_and_spare_the_domain() -> None:
    history = ["measured in the fifteenth session", "(issue 21)", "Issue #7 asked for it",
               'docs/DECISIONS.md, "Round 9"', "rounds 4-8", "this session's code", "two sessions ago",
               "the previous session's soak", "script /work/s16/pairs.sh", "see /root/notes",
               "a script in /tmp/sess/pairs2.sh", "in the 16th session"]
    domain = ["session 1 linked to the prior map", "the first session's experiences",
              "a session break edge", "the second session's first node", "every node of an earlier session",
              "a second lap of the same session", "where one session ends and the next begins",
              "bench_encoder.py --mission-only --rounds 2", "medians of 7 interleaved rounds",
              "NUMBA_CACHE_DIR=/tmp/poseidon-numba-cache", "--keep /tmp/sim10.mcap",
              "round(x, 3)", "a map of three sessions"]
    assert all(history_hits(t) for t in history), [t for t in history if not history_hits(t)]
    assert not any(history_hits(t) for t in domain), [t for t in domain if history_hits(t)]


def test_no_work_history_in_tracked_text_files() -> None:
    found = []
    for name in tracked_text_files():
        if name == SELF:
            continue
        path = REPO / name
        if not path.is_file():                      # deleted in the working tree, not yet in the index
            continue
        text = path.read_text(encoding="utf-8", errors="replace")
        found += [f"{name}:{no}: [{kind}] {line}" for no, kind, line in history_hits(text)]
    assert not found, f"{len(found)} work-history phrase(s):\n" + "\n".join(found)
