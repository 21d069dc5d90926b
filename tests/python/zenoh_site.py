"""A Zenoh peer from another codebase (eclipse-zenoh, Python) standing where a site daemon
will, for tests/zenoh_zone.rs.

    zenoh_site.py tcp/127.0.0.1:PORT SITE

Listens on the endpoint (multicast scouting off), prints "listening" once open, then one JSON
line per thing it hears under scanfuse/SITE/: a zone's liveliness token coming or going
({"event": "alive", "key", "kind": "put"|"delete"}) and each zone's poses ({"event": "poses",
"key", "encoding", ...the payload's fields}). Exits when stdin closes.
"""

import json
import sys

import zenoh


def main():
    endpoint, site = sys.argv[1:3]
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("listen/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(conf)

    def say(obj):
        print(json.dumps(obj), flush=True)

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
    sys.stdin.read()
    alive.undeclare()
    poses.undeclare()
    session.close()


main()
