"""Reads a scanfuse recording with the official Python mcap reader and protobuf decoder.

Prints one JSON object: per topic the message count, schema, and the first message's
frame_id, start/end angle, first three ranges and intensity count; plus the metadata records.
scanfuse's interop test compares this with what it wrote.
"""

import json
import sys

from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

out = {"topics": {}, "metadata": []}
with open(sys.argv[1], "rb") as f:
    reader = make_reader(f, decoder_factories=[DecoderFactory()])
    for schema, channel, message, decoded in reader.iter_decoded_messages():
        t = out["topics"].setdefault(channel.topic, {"count": 0, "schema": schema.name})
        t["count"] += 1
        if t["count"] == 1:
            t["frame_id"] = decoded.frame_id
            t["stamp_ns"] = decoded.timestamp.seconds * 1_000_000_000 + decoded.timestamp.nanos
            t["start_angle"] = decoded.start_angle
            t["end_angle"] = decoded.end_angle
            t["ranges"] = len(decoded.ranges)
            t["first_ranges"] = list(decoded.ranges[:3])
            t["intensities"] = len(decoded.intensities)
    f.seek(0)
    for record in make_reader(f).iter_metadata():
        out["metadata"].append({"name": record.name, "metadata": dict(record.metadata)})
json.dump(out, sys.stdout)
