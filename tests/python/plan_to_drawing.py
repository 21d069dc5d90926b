"""Exports a scanfuse floor plan (fixtures/plans/*.toml) as an architect's drawing would
carry it, written by an independent codebase (ezdxf for DXF; SVG as plain text), for
tests/drawing_align.rs.

    plan_to_drawing.py PLAN.toml OUT.dxf OUT.svg [--move-wall I:J:DM] [--clutter N]

DXF: millimetres ($INSUNITS = 4). The outer wall (the first [[wall]]) as one closed
LWPOLYLINE on A-WALL; other walls as LINEs on A-WALL, one of them through a block (its
entities on layer 0, inserted on A-WALL, rotated, unevenly scaled, from a base point, nested
one level); pillars (boxes up to 1 m) as a nested, rotated, unevenly scaled block on A-COLS;
circles as CIRCLEs; furniture (larger boxes, which scanners see but a drawing of the building
does not hold as walls) on FURNITURE; text on A-TEXT; a dimension on A-DIMS; door swings as
ARCs on A-DOOR. `--move-wall I:J:DM` draws segment J of wall I shifted DM metres along its
left normal: a wall moved since the drawing was made. `--clutter N` adds N more entities
(desks, chairs as circles, labels) on FURNITURE and A-TEXT, for timing a drawing of N entities. SVG: the same walls and pillars, 1 unit
= 1 cm, y down (so the reader's y flip gives the plan back), layers as <g id=…>.
"""

import math
import sys
import tomllib

import ezdxf


def segments(wall):
    pts = wall["points"]
    n = len(pts)
    count = n if wall.get("closed", False) else n - 1
    return [(pts[i], pts[(i + 1) % n]) for i in range(count)]


def moved(seg, dm):
    (x0, y0), (x1, y1) = seg
    dx, dy = x1 - x0, y1 - y0
    ln = math.hypot(dx, dy)
    nx, ny = -dy / ln, dx / ln
    return ((x0 + nx * dm, y0 + ny * dm), (x1 + nx * dm, y1 + ny * dm))


def main():
    plan_path, dxf_path, svg_path = sys.argv[1:4]
    move = None
    clutter = 0
    rest = sys.argv[4:]
    while rest:
        flag, value, rest = rest[0], rest[1], rest[2:]
        if flag == "--move-wall":
            i, j, dm = value.split(":")
            move = (int(i), int(j), float(dm))
        elif flag == "--clutter":
            clutter = int(value)
        else:
            sys.exit(f"unknown option {flag}")
    with open(plan_path, "rb") as f:
        plan = tomllib.load(f)
    walls = plan.get("wall", [])
    boxes = plan.get("box", [])
    circles = plan.get("circle", [])

    # Wall pieces in metres, by wall.
    pieces = []
    for wi, wall in enumerate(walls):
        segs = segments(wall)
        if move and move[0] == wi:
            segs[move[1]] = moved(segs[move[1]], move[2])
        pieces.append(segs)

    mm = 1000.0
    doc = ezdxf.new("R2013", setup=True)
    doc.header["$INSUNITS"] = 4
    for name in ["A-WALL", "A-COLS", "FURNITURE", "A-TEXT", "A-DIMS", "A-DOOR"]:
        doc.layers.add(name)
    msp = doc.modelspace()

    # Outer wall: closed LWPOLYLINE when unmoved, else its pieces as LINEs.
    for wi, segs in enumerate(pieces):
        wall = walls[wi]
        if wi == 0 and not (move and move[0] == 0):
            pts = [(x * mm, y * mm) for x, y in wall["points"]]
            msp.add_lwpolyline(pts, close=wall.get("closed", False), dxfattribs={"layer": "A-WALL"})
            continue
        for k, (a, b) in enumerate(segs):
            if wi == 1 and k == 0:
                # Through a block: a unit line from base point (1, 1) → (2, 1) (block units:
                # mm), inserted scaled by the wall's length along x and rotated to its heading.
                name = f"WALLPIECE{wi}_{k}"
                blk = doc.blocks.new(name=name, base_point=(1, 1))
                blk.add_line((1, 1), (2, 1), dxfattribs={"layer": "0"})
                ln = math.hypot(b[0] - a[0], b[1] - a[1]) * mm
                rot = math.degrees(math.atan2(b[1] - a[1], b[0] - a[0]))
                msp.add_blockref(
                    name,
                    (a[0] * mm, a[1] * mm),
                    dxfattribs={"layer": "A-WALL", "xscale": ln, "yscale": 3.0, "rotation": rot},
                )
            else:
                msp.add_line((a[0] * mm, a[1] * mm), (b[0] * mm, b[1] * mm), dxfattribs={"layer": "A-WALL"})

    # Pillars: a unit square block (base point at its centre) nested in a block that holds it
    # turned 90°, inserted scaled to the pillar's size.
    unit = doc.blocks.new(name="UNITSQ", base_point=(0.5, 0.5))
    unit.add_lwpolyline([(0, 0), (1, 0), (1, 1), (0, 1)], close=True, dxfattribs={"layer": "0"})
    col = doc.blocks.new(name="COLUMN", base_point=(0, 0))
    col.add_blockref("UNITSQ", (0, 0), dxfattribs={"layer": "0", "rotation": 90})
    for bx in boxes:
        cx, cy = bx["center"]
        sx, sy = bx["size"]
        yaw = bx.get("yaw_deg", 0.0)
        if max(sx, sy) <= 1.0:
            # COLUMN turns the square 90°, so its x scale sizes the plan's y.
            msp.add_blockref(
                "COLUMN",
                (cx * mm, cy * mm),
                dxfattribs={"layer": "A-COLS", "xscale": sy * mm, "yscale": sx * mm, "rotation": yaw},
            )
        else:
            c, s = math.cos(math.radians(yaw)), math.sin(math.radians(yaw))
            corners = [(-sx / 2, -sy / 2), (sx / 2, -sy / 2), (sx / 2, sy / 2), (-sx / 2, sy / 2)]
            pts = [((cx + c * x - s * y) * mm, (cy + s * x + c * y) * mm) for x, y in corners]
            msp.add_lwpolyline(pts, close=True, dxfattribs={"layer": "FURNITURE"})
    for ci in circles:
        cx, cy = ci["center"]
        msp.add_circle((cx * mm, cy * mm), ci["radius_m"] * mm, dxfattribs={"layer": "A-COLS"})
    for door in plan.get("door", []):
        x, y = door["at"]
        w = door.get("width_m", 0.9) * mm
        msp.add_arc((x * mm, y * mm), w, 0, 90, dxfattribs={"layer": "A-DOOR"})
    msp.add_text("HALL 3F", dxfattribs={"layer": "A-TEXT", "height": 500}).set_placement((2000, 2000))
    first = pieces[0][0]
    dim = msp.add_linear_dim(
        base=(first[0][0] * mm, first[0][1] * mm - 1500),
        p1=(first[0][0] * mm, first[0][1] * mm),
        p2=(first[1][0] * mm, first[1][1] * mm),
        dxfattribs={"layer": "A-DIMS"},
    )
    dim.render()
    # Clutter inside the outline's bounding box: a third each desks, chairs, labels.
    xs = [x for x, _ in walls[0]["points"]]
    ys = [y for _, y in walls[0]["points"]]
    for k in range(clutter):
        x = min(xs) + (max(xs) - min(xs)) * ((k * 0.618034) % 1.0)
        y = min(ys) + (max(ys) - min(ys)) * ((k * 0.414214) % 1.0)
        if k % 3 == 0:
            pts = [(x, y), (x + 1.2, y), (x + 1.2, y + 0.6), (x, y + 0.6)]
            msp.add_lwpolyline([(a * mm, b * mm) for a, b in pts], close=True, dxfattribs={"layer": "FURNITURE"})
        elif k % 3 == 1:
            msp.add_circle((x * mm, y * mm), 250, dxfattribs={"layer": "FURNITURE"})
        else:
            msp.add_text(f"D{k}", dxfattribs={"layer": "A-TEXT", "height": 200}).set_placement((x * mm, y * mm))
    doc.saveas(dxf_path)

    # SVG: 1 unit = 1 cm, y down.
    cm = 100.0
    out = ['<svg xmlns="http://www.w3.org/2000/svg" width="5000" height="5000">']
    out.append('<g id="A-WALL" stroke="black" fill="none">')
    for segs in pieces:
        for a, b in segs:
            out.append(
                f'<line x1="{a[0] * cm:.3f}" y1="{-a[1] * cm:.3f}" x2="{b[0] * cm:.3f}" y2="{-b[1] * cm:.3f}"/>'
            )
    out.append("</g>")
    out.append('<g id="A-COLS" stroke="black" fill="none">')
    for bx in boxes:
        cx, cy = bx["center"]
        sx, sy = bx["size"]
        if max(sx, sy) <= 1.0:
            yaw = bx.get("yaw_deg", 0.0)
            out.append(
                f'<rect x="{-sx * cm / 2:.3f}" y="{-sy * cm / 2:.3f}" width="{sx * cm:.3f}" height="{sy * cm:.3f}" '
                f'transform="translate({cx * cm:.3f},{-cy * cm:.3f}) rotate({-yaw:.3f})"/>'
            )
    out.append("</g>")
    out.append('<g id="A-TEXT"><text x="200" y="-200">HALL 3F</text></g>')
    out.append("</svg>")
    with open(svg_path, "w") as f:
        f.write("\n".join(out))


if __name__ == "__main__":
    main()
