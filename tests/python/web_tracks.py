"""The page draws tracks: headless Chromium (Playwright) opens a page whose daemon streams
TRACKS, waits until every expected track is drawn as a `[data-track]` element, and prints a
JSON summary: the ids drawn, their screen positions, and the People panel's text. Run by
tests/web_page_tracks.rs:

    python web_tracks.py --url http://127.0.0.1:PORT/ --ids 3,8 --browser /usr/bin/chromium
"""

import argparse
import json
import time
import sys

from playwright.sync_api import sync_playwright


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--url", required=True)
    ap.add_argument("--ids", required=True)
    ap.add_argument("--browser", default="/usr/bin/chromium")
    ap.add_argument("--screenshot")
    args = ap.parse_args()
    want = sorted(args.ids.split(","))
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=args.browser, args=["--no-sandbox"])
        page = browser.new_page(viewport={"width": 1200, "height": 800})
        page.goto(args.url)
        selector = ",".join(f'[data-track="{i}"]' for i in want)
        # Polled from here: the page's Content-Security-Policy forbids the eval that
        # wait_for_function would need.
        deadline = time.monotonic() + 30
        while page.locator(selector).count() != len(want):
            if time.monotonic() > deadline:
                raise SystemExit(f"the page drew {page.locator(selector).count()} of {want}")
            page.wait_for_timeout(100)
        # The trail needs two positions of each; let a few more TRACKS arrive.
        page.wait_for_timeout(1000)
        drawn = {}
        for el in page.query_selector_all("[data-track]"):
            box = el.bounding_box()
            drawn[el.get_attribute("data-track")] = {
                "text": el.text_content(),
                "x": box["x"] + box["width"] / 2 if box else None,
                "y": box["y"] + box["height"] / 2 if box else None,
            }
        counts = page.inner_text("#counts")
        if args.screenshot:
            page.screenshot(path=args.screenshot)
        browser.close()
    json.dump({"drawn": drawn, "counts": counts}, sys.stdout)


if __name__ == "__main__":
    main()
