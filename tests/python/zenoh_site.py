"""A Zenoh router from another codebase (eclipse-zenoh, Python) standing where a site daemon
will, for tests/zenoh_zone.rs.

    zenoh_site.py tcp/127.0.0.1:PORT SITE

Listens on the endpoint (multicast scouting off), prints "listening" once open, then one JSON
line per thing it hears under scanfuse/SITE/: a zone's liveliness token coming or going
({"event": "alive", "key", "kind": "put"|"delete"}) and each zone's poses ({"event": "poses",
"key", "encoding", ...the payload's fields}). A line on stdin is a query (see below). Exits
when stdin closes.
"""

import json
import sys
import threading

import zenoh


def main():
    endpoint, site = sys.argv[1:3]
    conf = zenoh.Config()
    # A router, as the site daemon hosting one in-process will be: it routes between zones.
    conf.insert_json5("mode", '"router"')
    conf.insert_json5("listen/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(conf)

    # Zenoh calls back on its own threads: one line at a time, whole.
    lock = threading.Lock()

    def say(obj):
        with lock:
            sys.stdout.write(json.dumps(obj) + "\n")
            sys.stdout.flush()

    def on_alive(sample):
        kind = "put" if sample.kind == zenoh.SampleKind.PUT else "delete"
        say({"event": "alive", "key": str(sample.key_expr), "kind": kind})

    def on_poses(sample):
        try:
            body = json.loads(sample.payload.to_string())
        except ValueError as e:
            body = {"error": f"not JSON: {e}"}
        say({"event": "poses", "key": str(sample.key_expr), "encoding": str(sample.encoding), **body})

    alive = session.liveliness().declare_subscriber(f"scanfuse/{site}/*/alive", on_alive, history=True)
    poses = session.declare_subscriber(f"scanfuse/{site}/*/poses", on_poses)
    say({"event": "listening"})
    # Each line on stdin is a key expression to query ("get" in Zenoh's words); each reply is
    # printed ({"event": "reply", "key", "encoding", ...the payload's fields, "ranges_m" as
    # its length}), then {"event": "replied", "count"}.
    for line in sys.stdin:
        count = 0
        for reply in session.get(line.strip(), timeout=10.0):
            if reply.ok is None:
                say({"event": "reply", "error": str(reply.err.payload.to_string())})
                continue
            sample = reply.ok
            body = json.loads(sample.payload.to_string())
            if isinstance(body.get("ranges_m"), list):
                body["ranges_m"] = len(body["ranges_m"])
            say({"event": "reply", "key": str(sample.key_expr), "encoding": str(sample.encoding), **body})
            count += 1
        say({"event": "replied", "count": count})
    alive.undeclare()
    poses.undeclare()
    session.close()


main()
