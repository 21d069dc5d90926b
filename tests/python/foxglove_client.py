"""A Foxglove WebSocket client from outside the repository's codebase: Python `websockets`
offering the `foxglove.sdk.v1` subprotocol, messages decoded with Python `protobuf` from the
FileDescriptorSet each channel advertises (no schema is shipped with this script).

Subscribes to every channel a running scanfuse advertises and checks that it receives:
a `foxglove.LaserScan` on /<id>/scan in the sensor's own frame with plausible ranges;
`foxglove.FrameTransforms` naming every placed sensor at the pose the status socket's `poses`
reports; the occupancy map as a `foxglove.Grid`. Run by tests/replay_servers.rs:

    python foxglove_client.py --url ws://127.0.0.1:PORT --socket PATH

Prints a JSON summary on stdout; exits non-zero with the reason when a check fails.
"""

import argparse
import base64
import json
import math
import socket
import struct
import sys
import time

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from websockets.sync.client import connect

SUBPROTOCOL = "foxglove.sdk.v1"
XY_TOL_M = 1e-6
YAW_TOL_DEG = 1e-4
# Binary server opcodes of the protocol.
MESSAGE_DATA = 0x01


def ask(path, request):
    """One request on the status socket; the reply (past the VERSION banner)."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
        s.settimeout(10)
        s.connect(path)
        f = s.makefile("rw")
        banner = json.loads(f.readline())
        assert banner["class"] == "VERSION", banner
        f.write(json.dumps(request) + "\n")
        f.flush()
        return json.loads(f.readline())


def placed(poses):
    return {
        s["id"]: (s["x_m"], s["y_m"], s["yaw_deg"])
        for s in poses["sensors"]
        if s["registered"] and "x_m" in s
    }


def message_class(channel):
    """The protobuf class of a channel, built from the schema it advertises."""
    if channel.get("encoding") != "protobuf" or channel.get("schemaEncoding") != "protobuf":
        raise ValueError(f"{channel['topic']}: not protobuf: {channel}")
    fds = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(channel["schema"]))
    pool = descriptor_pool.DescriptorPool()
    pending = list(fds.file)
    # Files in dependency order, whatever order the set has them in.
    while pending:
        progress = False
        for f in list(pending):
            try:
                pool.Add(f)
            except TypeError:
                continue
            pending.remove(f)
            progress = True
        if not progress:
            raise ValueError(f"{channel['topic']}: unresolvable schema files")
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(channel["schemaName"]))


def heading_deg(q):
    """The heading (yaw) of a rotation: where it turns +x, seen from above."""
    w, x, y, z = q.w, q.x, q.y, q.z
    vx = 1.0 - 2.0 * (y * y + z * z)
    vy = 2.0 * (x * y + w * z)
    return math.degrees(math.atan2(vy, vx))


def yaw_diff(a, b):
    return abs((a - b + 180.0) % 360.0 - 180.0)


def plausible_scan(topic, m):
    sensor = topic.strip("/").split("/")[0]
    if m.frame_id != sensor:
        return f"{topic}: frame_id {m.frame_id!r}, not the sensor's own {sensor!r}"
    if not (m.end_angle > m.start_angle and m.end_angle - m.start_angle <= 2 * math.pi + 1e-9):
        return f"{topic}: angles {m.start_angle}..{m.end_angle}"
    if len(m.ranges) < 100:
        return f"{topic}: only {len(m.ranges)} ranges"
    good = [r for r in m.ranges if math.isfinite(r) and 0.02 < r < 100.0]
    if len(good) < 0.5 * len(m.ranges):
        return f"{topic}: only {len(good)} of {len(m.ranges)} ranges are returns"
    if not any(r > 1.0 for r in good):
        return f"{topic}: no return beyond 1 m in a hall"
    return None


def tf_agrees(tf, socket_poses):
    """None when the transforms name exactly the placed sensors at their poses, else why."""
    if set(tf) != set(socket_poses):
        return f"transforms name {sorted(tf)}, poses has {sorted(socket_poses)} placed"
    for sid, (x, y, yaw) in socket_poses.items():
        tx, ty, tyaw = tf[sid]
        if abs(tx - x) > XY_TOL_M or abs(ty - y) > XY_TOL_M or yaw_diff(tyaw, yaw) > YAW_TOL_DEG:
            return f"{sid}: transform ({tx}, {ty}, {tyaw}°), poses ({x}, {y}, {yaw}°)"
    return None


def check_grid(m):
    names = [f.name for f in m.fields]
    if m.frame_id != "site" or "occupancy" not in names:
        return f"grid: frame {m.frame_id!r}, fields {names}"
    if m.column_count == 0 or m.row_stride < m.column_count * m.cell_stride:
        return f"grid: {m.column_count} columns, row stride {m.row_stride}"
    rows = len(m.data) // m.row_stride
    if rows == 0 or len(m.data) != rows * m.row_stride:
        return f"grid: {len(m.data)} bytes is not whole rows of {m.row_stride}"
    values = set(m.data)
    if 100 not in values or 0 not in values:
        return f"grid: no walls or no free space (values {sorted(values)[:8]})"
    return None


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--url", required=True)
    ap.add_argument("--socket", required=True)
    ap.add_argument("--seconds", type=float, default=60.0)
    args = ap.parse_args()

    classes = {}  # channel id -> (topic, schema name, class)
    subscriptions = {}  # subscription id -> channel id
    scans = {}  # topic -> first plausible LaserScan
    scan_problem = None
    tf = {}  # sensor -> (x, y, yaw_deg), the latest transforms
    tf_problem = "no FrameTransforms yet"
    grid = None
    grid_problem = "no Grid yet"
    points = 0
    scene = 0
    deadline = time.monotonic() + args.seconds
    last_check = 0.0

    with connect(args.url, subprotocols=[SUBPROTOCOL], max_size=None, open_timeout=10) as ws:
        if ws.subprotocol != SUBPROTOCOL:
            sys.exit(f"the server chose subprotocol {ws.subprotocol!r}")
        while time.monotonic() < deadline:
            try:
                frame = ws.recv(timeout=0.5)
            except TimeoutError:
                frame = None
            if isinstance(frame, str):
                msg = json.loads(frame)
                if msg.get("op") == "advertise":
                    subs = []
                    for ch in msg["channels"]:
                        classes[ch["id"]] = (ch["topic"], ch["schemaName"], message_class(ch))
                        sub_id = len(subscriptions) + 1
                        subscriptions[sub_id] = ch["id"]
                        subs.append({"id": sub_id, "channelId": ch["id"]})
                    ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
            elif isinstance(frame, bytes) and frame and frame[0] == MESSAGE_DATA:
                sub_id, _log_time = struct.unpack_from("<IQ", frame, 1)
                topic, schema, cls = classes[subscriptions[sub_id]]
                m = cls.FromString(frame[13:])
                if schema == "foxglove.LaserScan":
                    if not topic.endswith("/scan"):
                        sys.exit(f"a LaserScan on {topic}")
                    why = plausible_scan(topic, m)
                    if why is None:
                        scans.setdefault(topic, m)
                    else:
                        scan_problem = why
                elif schema == "foxglove.FrameTransforms":
                    tf = {}
                    for t in m.transforms:
                        if t.parent_frame_id != "site":
                            sys.exit(f"transform to {t.child_frame_id} from {t.parent_frame_id!r}")
                        tf[t.child_frame_id] = (
                            t.translation.x,
                            t.translation.y,
                            heading_deg(t.rotation),
                        )
                    last_check = 0.0
                elif schema == "foxglove.Grid":
                    grid_problem = check_grid(m)
                    if grid_problem is None:
                        grid = m
                elif schema == "foxglove.PointCloud":
                    points = max(points, len(m.data) // max(m.point_stride, 1))
                elif schema == "foxglove.SceneUpdate":
                    scene = max(scene, len(m.entities))
            now = time.monotonic()
            if tf and now - last_check > 0.5:
                last_check = now
                socket_poses = placed(ask(args.socket, {"cmd": "poses"}))
                tf_problem = tf_agrees(tf, socket_poses) if len(socket_poses) >= 2 else (
                    f"only {len(socket_poses)} sensors placed yet"
                )
            if scans and tf_problem is None and grid is not None:
                break

    failures = []
    if not scans:
        failures.append(scan_problem or "no LaserScan received")
    if tf_problem is not None:
        failures.append(tf_problem)
    if grid is None:
        failures.append(grid_problem)
    summary = {
        "scan_topics": sorted(scans),
        "transforms": {k: list(v) for k, v in sorted(tf.items())},
        "grid": [grid.column_count, len(grid.data) // grid.row_stride] if grid else None,
        "points": points,
        "scene_entities": scene,
    }
    print(json.dumps(summary))
    if failures:
        sys.exit("; ".join(failures))


if __name__ == "__main__":
    main()
