"""A hostile session for the secured multi-host test: joins a router (or fails to), subscribes
to some keys and puts forged messages on others until SIGTERM (or ``--seconds``), then prints
a JSON report on stdout: ``joined``, ``received`` {key: samples}, ``data`` {key: data frames
among them (the rest are watermarks and end-of-stream)}, ``put`` {key: attempts},
``error`` (why it could not join).

python -m tests.launcher.intruder ENDPOINT TLS_DIR TLS_HOST [--user U --password-file F]
    [--put KEY]... [--subscribe KEY]... [--seconds S]

Forged messages are schema-valid (an ``Odometry`` far away, a 2x2 camera ``Image``), so a
recorder would record them if the router let them through.
"""
import argparse
import json
import os
import threading
import time

import numpy as np
import zenoh

from common.bus import zenoh_config
from common.codec import decode_frame, encode_frame
from common.messages import Header, Image, Odometry
from launcher.service_cmd import _Signals


def forged(key: str, seq: int):
    header = Header(seq=seq, stamp=1_372_687_208_000_000_000 + seq, frame_id="intruder")
    if key.endswith("image_raw"):
        return Image(header=header, height=2, width=2, data=np.full((2, 2, 3), 255, np.uint8))
    return Odometry(header=header, position=[666.0, 0.0, 0.0], orientation=[0.0, 0.0, 0.0, 1.0])


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("endpoint")
    ap.add_argument("tls_dir")
    ap.add_argument("tls_host")
    ap.add_argument("--user")
    ap.add_argument("--password-file")
    ap.add_argument("--namespace", default="poseidon")
    ap.add_argument("--put", action="append", default=[])
    ap.add_argument("--subscribe", action="append", default=[])
    ap.add_argument("--seconds", type=float, default=300.0)
    args = ap.parse_args()
    stop = threading.Event()
    conf = zenoh_config("client", connect=[args.endpoint], config_file="deploy/zenoh/secured-service.json5",
                        tls_dir=args.tls_dir, tls_host=args.tls_host, user=args.user,
                        password_file=args.password_file)
    conf.insert_json5("connect/timeout_ms", "4000")
    conf.insert_json5("connect/exit_on_failure", "true")
    report: dict = {"joined": False, "received": {k: 0 for k in args.subscribe},
                    "data": {k: 0 for k in args.subscribe}, "put": {k: 0 for k in args.put}}
    lock = threading.Lock()
    printed = threading.Event()

    def print_report_and_exit() -> None:
        """The report once, then exit without waiting for Zenoh's teardown: a session on a
        router that refuses us can keep a put or close in native code for a long time."""
        with lock:
            if not printed.is_set():
                printed.set()
                print(json.dumps(report), flush=True)
        os._exit(0)

    def on_stop() -> None:
        """The first SIGTERM: end the loop; if the main thread is still held in a Zenoh call
        5 s later, report and exit anyway."""
        stop.set()
        timer = threading.Timer(5.0, print_report_and_exit)
        timer.daemon = True
        timer.start()

    # the services' signal handling: SIGTERM is seen by a watcher thread, so a main thread held
    # in a Zenoh call cannot delay the report
    _Signals("intruder").on_stop(on_stop)

    try:
        session = zenoh.open(conf)
    except zenoh.ZError as exc:
        report["error"] = str(exc)[:300]
        print_report_and_exit()
    report["joined"] = True

    def counter(key: str):
        def on_sample(sample: zenoh.Sample) -> None:
            with lock:
                report["received"][key] += 1
                report["data"][key] += decode_frame(sample.payload.to_bytes()).kind == "data"
        return on_sample

    subs = [session.declare_subscriber(f"{args.namespace}/{k}", counter(k)) for k in args.subscribe]
    pubs = {k: session.declare_publisher(f"{args.namespace}/{k}") for k in args.put}
    print("ready", flush=True)  # the test waits for this line before it starts the run
    t_end = time.monotonic() + args.seconds
    seq = 0
    while not stop.is_set() and time.monotonic() < t_end:
        for key, pub in pubs.items():
            pub.put(encode_frame(forged(key, seq)))
            with lock:
                report["put"][key] += 1
        seq += 1
        stop.wait(0.05)
    for sub in subs:
        sub.undeclare()
    closer = threading.Thread(target=session.close, daemon=True)
    closer.start()
    closer.join(5.0)
    print_report_and_exit()


if __name__ == "__main__":
    main()
