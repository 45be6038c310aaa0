"""A hostile session for the secured multi-host test: tries to join a router, subscribe to
the camera and put forged Odometry for a while; prints a JSON report on stdout.

python -m tests.foundation.intruder ENDPOINT TLS_DIR TLS_HOST [USER PASSWORD_FILE] SECONDS
"""
import json
import sys
import time

import zenoh

from common.bus import zenoh_config
from common.codec import encode_frame
from common.messages import Header, Odometry


def main() -> None:
    endpoint, tls_dir, host = sys.argv[1:4]
    user, pw = (sys.argv[4], sys.argv[5]) if len(sys.argv) > 6 else (None, None)
    seconds = float(sys.argv[-1])
    conf = zenoh_config("client", connect=[endpoint], config_file="deploy/zenoh/secured-service.json5",
                        tls_dir=tls_dir, tls_host=host, user=user, password_file=pw)
    conf.insert_json5("connect/timeout_ms", "4000")
    conf.insert_json5("connect/exit_on_failure", "true")
    report = {"joined": False, "camera_received": 0, "odometry_put": 0}
    try:
        session = zenoh.open(conf)
    except zenoh.ZError as exc:
        report["error"] = str(exc)[:300]
        print(json.dumps(report))
        return
    report["joined"] = True

    def on_camera(_sample):
        report["camera_received"] += 1

    sub = session.declare_subscriber("poseidon/camera/image_raw", on_camera)
    pub = session.declare_publisher("poseidon/Odometry")
    t_end = time.monotonic() + seconds
    seq = 0
    while time.monotonic() < t_end:
        forged = Odometry(header=Header(seq=seq, stamp=1_372_687_208_000_000_000 + seq), position=[666.0, 0.0, 0.0],
                          orientation=[0.0, 0.0, 0.0, 1.0])
        pub.put(encode_frame(forged))
        report["odometry_put"] += 1
        seq += 1
        time.sleep(0.05)
    sub.undeclare()
    session.close()
    print(json.dumps(report))


if __name__ == "__main__":
    main()
