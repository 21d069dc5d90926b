"""The live page in a real browser (headless Chromium driven by Playwright).

Opens the page a running daemon serves, waits until it is drawn, checks each sensor drawn on
the page (its data-sensor and data-pose) against the status socket's `poses` reply, drags
one sensor, and checks that `poses` then shows it surveyed where it was dropped. Saves a
screenshot before the drag (FILE-before.png), with two point pairs listed (FILE-pairs.png,
with --drawing) and after the drag (FILE). Run by tests/web_page_browser.rs:

    python web_page.py --url http://127.0.0.1:PORT/ --socket PATH --screenshot FILE.png [--drawing]

With --drawing the daemon has a building drawing and an alignment to it: the page must draw
the drawing under the map (`data-drawing` on the canvas), and the drawing's walls must lie on
the scans' walls on screen: the summary gives the drawn segment count and the median screen
distance (px) from the scan points near a drawn wall to that wall. Then two map points are
picked on the page and paired with where the current alignment puts them on the drawing,
10 cm off, and "Align from pairs" must replace the alignment with one made from the pairs
(`page_align` in the summary: `building_from_site` as `poses` then has it).
"""

import math

import argparse
import json
import socket
import sys
import time

from playwright.sync_api import sync_playwright

XY_TOL_M = 0.01
YAW_TOL_DEG = 0.1


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


def drawn(page):
    """{id: (x, y, yaw)} of every sensor drawn on the page."""
    out = {}
    for el in page.query_selector_all("[data-sensor]"):
        x, y, yaw = (float(v) for v in el.get_attribute("data-pose").split())
        out[el.get_attribute("data-sensor")] = (x, y, yaw)
    return out


def yaw_diff(a, b):
    return abs((a - b + 180.0) % 360.0 - 180.0)


def placed(poses):
    return {
        s["id"]: (s["x_m"], s["y_m"], s["yaw_deg"])
        for s in poses["sensors"]
        if s["registered"] and "x_m" in s
    }


def agree(page_poses, socket_poses):
    if set(page_poses) != set(socket_poses):
        return False
    for sid, (x, y, yaw) in socket_poses.items():
        px, py, pyaw = page_poses[sid]
        if abs(px - x) > XY_TOL_M or abs(py - y) > XY_TOL_M or yaw_diff(pyaw, yaw) > YAW_TOL_DEG:
            return False
    return True


def seg_px(p, seg, scale):
    """Screen distance (px) from site point p to segment seg = (ax, ay, bx, by)."""
    ax, ay, bx, by = seg
    dx, dy = bx - ax, by - ay
    ln2 = dx * dx + dy * dy
    t = 0.0 if ln2 == 0 else max(0.0, min(1.0, ((p[0] - ax) * dx + (p[1] - ay) * dy) / ln2))
    ex, ey = ax + t * dx - p[0], ay + t * dy - p[1]
    return (ex * ex + ey * ey) ** 0.5 * scale


def drawing_fit(page):
    """(segments drawn, median px from scan points within 0.3 m of a drawn wall to it,
    points counted): the drawing's walls against where the scans put the walls, on screen."""
    view = page.evaluate(
        "() => ({d: st.drawing, frames: st.frames, scale: st.scale,"
        " drawn: canvas.getAttribute('data-drawing')})"
    )
    d, scale = view["d"] or [], view["scale"]
    segs = [tuple(d[i : i + 4]) for i in range(0, len(d) - 3, 4)]
    dists = []
    for xy in view["frames"].values():
        for i in range(0, len(xy) - 1, 6):
            p = (xy[i], xy[i + 1])
            best = min((seg_px(p, s, scale) for s in segs), default=None)
            if best is not None and best <= 0.3 * scale:
                dists.append(best)
    dists.sort()
    median = dists[len(dists) // 2] if dists else None
    return int(view["drawn"] or 0), median, len(dists)


def to_drawing(b, x, y):
    """Site point (x, y) in the drawing's frame through building_from_site b."""
    c, s = math.cos(math.radians(b["yaw_deg"])), math.sin(math.radians(b["yaw_deg"]))
    return (b["x_m"] + b["scale"] * (c * x - s * y), b["y_m"] + b["scale"] * (s * x + c * y))


def floor_point(page, x, y):
    """A screen point near (x, y) on the bare floor (not on a sensor's glyph)."""
    for dx in (0, 40, -40, 80, -80):
        on_glyph = page.evaluate(
            "([x, y]) => !!(document.elementFromPoint(x, y) || {closest: () => null})"
            ".closest('g.glyph')",
            [x + dx, y],
        )
        if not on_glyph:
            return x + dx, y
    sys.exit(f"no bare floor near {x}, {y} to pick")


def align_by_pairs(page, sock, screenshot):
    """Picks two map points on the page, pairs each with where the current alignment puts it
    on the drawing (10 cm off), aligns from the pairs; `building_from_site` after."""
    before = ask(sock, {"cmd": "poses"})["building_from_site"]
    box = page.locator("#overlay").bounding_box()
    cx, cy = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
    for sx, sy in ((cx - 180, cy - 60), (cx + 180, cy + 80)):
        page.click("#pick")
        page.mouse.click(*floor_point(page, sx, sy))
        site = page.get_attribute("#pick-at", "data-site")
        if not site:
            sys.exit(f"picking a map point at {sx:.0f}, {sy:.0f} left no data-site on #pick-at")
        x, y = (float(v) for v in site.split())
        dx, dy = to_drawing(before, x, y)
        page.fill("#draw-x", f"{dx + 0.1:.3f}")
        page.fill("#draw-y", f"{dy - 0.1:.3f}")
        page.click("#add-pair")
    if page.locator("#pairs li").count() != 2:
        sys.exit("the two pairs are not listed")
    page.screenshot(path=screenshot)
    page.click("#align-pairs")
    until(
        lambda: "the page to show the alignment from the pairs:"
        f" #building says {page.inner_text('#building')!r}, the toast"
        f" {page.inner_text('#toast')!r}, pairs"
        f" {[li.get_attribute('data-pair') for li in page.query_selector_all('#pairs li')]}",
        30,
        lambda: page.get_attribute("#building", "data-method") == "pairs+lines",
    )
    return ask(sock, {"cmd": "poses"})["building_from_site"]


def until(what, seconds, check):
    """`check()` once it is truthy; else exits naming `what` (a string, or a function that
    describes what the page shows at the time out)."""
    end = time.monotonic() + seconds
    last = None
    while time.monotonic() < end:
        last = check()
        if last:
            return last
        time.sleep(0.25)
    sys.exit(f"timed out after {seconds} s waiting for {what() if callable(what) else what}")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--url", required=True)
    ap.add_argument("--socket", required=True)
    ap.add_argument("--screenshot", required=True)
    ap.add_argument("--browser", default="/usr/bin/chromium")
    ap.add_argument("--drawing", action="store_true")
    args = ap.parse_args()

    with sync_playwright() as p:
        browser = p.chromium.launch(
            executable_path=args.browser, headless=True, args=["--no-sandbox"]
        )
        page = browser.new_page(viewport={"width": 1280, "height": 800})
        errors = []
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.goto(args.url)
        page.wait_for_selector('body[data-ready="1"]', timeout=60_000)

        # Every placed sensor drawn where the socket says it stands (registration may still
        # be settling: both are read again until they agree).
        def same():
            socket_poses = placed(ask(args.socket, {"cmd": "poses"}))
            page_poses = drawn(page)
            if len(socket_poses) >= 2 and agree(page_poses, socket_poses):
                return socket_poses
            return None

        before = until("the page to show every placed sensor as `poses` has it", 60, same)
        time.sleep(1.0)  # a map and a status round more, for the picture
        page.screenshot(path=args.screenshot.replace(".png", "-before.png"))
        drawing = page_align = None
        if args.drawing:
            until(
                "the page to draw the building drawing (data-drawing)",
                20,
                lambda: page.get_attribute("canvas", "data-drawing"),
            )
            drawing = drawing_fit(page)
            page_align = align_by_pairs(
                page, args.socket, args.screenshot.replace(".png", "-pairs.png")
            )
        anchor = ask(args.socket, {"cmd": "poses"})["anchor"]
        sensor = next(sid for sid in sorted(before) if sid != anchor)

        # Drag it: press on its glyph, move, release.
        box = page.locator(f'[data-sensor="{sensor}"] .body').bounding_box()
        x0, y0 = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
        page.mouse.move(x0, y0)
        page.mouse.down()
        page.mouse.move(x0 + 30, y0 - 20, steps=12)
        page.mouse.up()
        bx, by, byaw = before[sensor]

        def moved_from(p):
            return ((p[0] - bx) ** 2 + (p[1] - by) ** 2) ** 0.5

        # The glyph is redrawn on the page's next animation frame, which a loaded machine may
        # not have run yet when the mouse is released: wait for it, not for a fixed time.
        dropped = until(
            lambda: f"the drag to move {sensor} on the page: {before[sensor]} → {drawn(page)[sensor]}",
            10,
            lambda: drawn(page)[sensor] if moved_from(drawn(page)[sensor]) >= 0.05 else None,
        )
        moved_m = moved_from(dropped)

        def surveyed_there():
            for s in ask(args.socket, {"cmd": "poses"})["sensors"]:
                if s["id"] != sensor:
                    continue
                if (
                    s.get("source") == "surveyed"
                    and abs(s["x_m"] - dropped[0]) <= XY_TOL_M
                    and abs(s["y_m"] - dropped[1]) <= XY_TOL_M
                    and yaw_diff(s["yaw_deg"], dropped[2]) <= YAW_TOL_DEG
                ):
                    return s
            return None

        after = until(f"`poses` to show {sensor} surveyed where it was dropped", 30, surveyed_there)
        # The page shows it there too, once its next poses arrive.
        until(
            "the page to show the surveyed pose",
            10,
            lambda: yaw_diff(drawn(page)[sensor][2], after["yaw_deg"]) <= YAW_TOL_DEG
            and abs(drawn(page)[sensor][0] - after["x_m"]) <= XY_TOL_M,
        )
        time.sleep(1.5)  # one more map and status round, for the picture
        page.screenshot(path=args.screenshot)
        browser.close()
        if errors:
            sys.exit(f"the page raised: {errors}")
        print(
            json.dumps(
                {
                    "sensors": sorted(before),
                    "dragged": sensor,
                    "from": before[sensor],
                    "to": [after["x_m"], after["y_m"], after["yaw_deg"]],
                    "moved_m": round(moved_m, 3),
                    "drawing_segments": drawing and drawing[0],
                    "drawing_median_px": drawing and drawing[1],
                    "drawing_points": drawing and drawing[2],
                    "page_align": page_align,
                }
            )
        )


if __name__ == "__main__":
    main()
