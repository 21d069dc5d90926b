"""Opens scanfuse's map files with common tools (Pillow, plyfile, PyYAML) and prints what they
see as JSON: image size and the count of each pixel value, the YAML keys, the PLY vertex count
and its properties. scanfuse's map-file test compares that with what it wrote."""

import json
import sys
from collections import Counter
from pathlib import Path

import yaml
from PIL import Image
from plyfile import PlyData

folder = Path(sys.argv[1])
meta = yaml.safe_load((folder / "map.yaml").read_text())
image = Image.open(folder / meta["image"])
ply = PlyData.read(str(folder / "map.ply"))
vertex = ply["vertex"]
print(json.dumps({
    "mode": image.mode,
    "size": list(image.size),
    "pixels": {str(k): v for k, v in Counter(image.getdata()).items()},
    "yaml": meta,
    "ply_vertices": vertex.count,
    "ply_properties": [p.name for p in vertex.properties],
    "ply_first": [float(vertex["x"][0]), float(vertex["y"][0]), int(vertex["sensor"][0])],
}))
