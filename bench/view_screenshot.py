#!/usr/bin/python3
"""The README's screenshot of `ltbake view`: the medium scene at R = 32 (bench/pbi_bake.toml,
baked by bench/pbi_sequences.py) under sunset.exr with PBI at 30 terms, taken in headless
Chromium right after a drag (the image still converging), through the browser test's
DevTools-over-a-pipe driver (tests/cli/view_browser_test.py).

    /usr/bin/python3 bench/view_screenshot.py [BUILD_DIR=build]   -> bench/results/view_page.png
"""
import base64
import os
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
BUILD = os.path.abspath(sys.argv[1] if len(sys.argv) > 1 else os.path.join(ROOT, "build"))
sys.argv = [sys.argv[0], os.path.join(BUILD, "ltbake")]  # the test module reads the binary from argv
sys.path.insert(0, os.path.join(ROOT, "tests", "cli"))
import view_browser_test as vb  # noqa: E402


def main():
    final = os.path.join(HERE, "out", "pbi", "final.ltm")
    if not os.path.exists(final):
        sys.exit(f"{final} is missing: run bench/pbi_sequences.py (or ltbake run bench/pbi_bake.toml) first")
    maps = subprocess.run(["bash", os.path.join(ROOT, "scripts", "find_envmaps.sh")], capture_output=True,
                          text=True).stdout.strip()
    exe = vb.find_chromium()
    if not exe:
        sys.exit("no headless Chromium: sudo apt-get install chromium-headless-shell")
    server = vb.Server(final, "--env", os.path.join(maps, "sunset.exr"), "--clamp", "--terms", 30, "--reference",
                       final)
    browser = None
    try:
        url = server.first_line()
        with tempfile.TemporaryDirectory() as d:
            browser = vb.Browser(exe, os.path.join(d, "profile"), os.path.join(d, "browser.log"))
            page = vb.Page(browser, url)
            page.wait_state(lambda s: s["frames"] >= 1 and s["stats"] is not None, "the first frame")
            box = page.eval("(() => { const r = document.getElementById('frame').getBoundingClientRect();"
                            " return [r.x + r.width / 2, r.y + r.height / 2]; })()")
            x, y = box
            page.mouse("mousePressed", x, y, 1)
            for k in range(1, 13):
                page.mouse("mouseMoved", x + 5 * k, y, 1)
            page.mouse("mouseReleased", x + 60, y, 0)
            page.wait_state(lambda s: s["last"] and float(s["last"]["rotate"]) >= 29.9, "the dragged frame")
            shot = page.send("Page.captureScreenshot", {"format": "png"})["data"]
            out = os.path.join(HERE, "results", "view_page.png")
            with open(out, "wb") as f:
                f.write(base64.b64decode(shot))
            print(f"wrote {out}")
    finally:
        if browser:
            browser.close()
        server.kill()


if __name__ == "__main__":
    main()
