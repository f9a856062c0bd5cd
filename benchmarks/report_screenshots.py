"""The report's screenshots in ``docs/``: the ``--html`` page of a good pair (side by side, *before* left of
*after*), of a likely wrong pair (its banner) and of a 15-scan set, made from the real scans committed under
``benchmarks/real_scans/data`` by the CLIs themselves, then opened in headless Chromium as ``tests/pages_test.py``
opens them (software WebGL), photographed and stored as 256-colour PNG (each well under 300 KB).

    python benchmarks/report_screenshots.py [--out docs] [--keep DIR]

Needs the ``[dev]`` extras (playwright, Pillow through matplotlib) and a Chromium (``chromium`` on the PATH, or
``RPMNET_CHROMIUM``). ``--keep DIR`` keeps the HTML pages there.

- good pair: ``rpmnet-register happyStandRight_24.ply happyStandRight_0.ply`` (24° apart: fitness 0.93);
- likely wrong: ``rpmnet-register happyStandRight_144.ply happyStandRight_0.ply`` (144° apart on the turntable,
  little overlap: the answer, a turn of about 13°, is flagged likely wrong);
- scan set: ``rpmnet-register-scans`` on the first 15 sweeps of ``kitti_04`` (a LiDAR street: the view opens
  z up, framed on the cloud).
"""

from __future__ import annotations

import argparse
import io
import os
import shutil
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
DATA = os.path.join(HERE, "real_scans", "data")
SIZE = (1280, 800)  # CSS pixels of the browser window
# WebGL without a GPU, as the tests run it
ARGS = ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader"]


def _run(module: str, args: list) -> None:
    """Runs ``python -m rpmnet_jax.cli.<module> ARGS``, echoing its output; stops on failure."""
    print(f"$ rpmnet-{module.replace('_', '-')} {' '.join(os.path.basename(a) for a in args)}", flush=True)
    subprocess.run([sys.executable, "-m", f"rpmnet_jax.cli.{module}", *args], check=True)


def pages(folder: str) -> dict:
    """Writes the three pages into ``folder``: ``{name: (page, button to click or None)}``."""
    stand = os.path.join(DATA, "happy_stand")
    good, wrong, scans = (os.path.join(folder, f"{n}.html") for n in ("good_pair", "likely_wrong", "scan_set"))
    _run("register", [os.path.join(stand, "happyStandRight_24.ply"), os.path.join(stand, "happyStandRight_0.ply"),
                      "--html", good])
    _run("register", [os.path.join(stand, "happyStandRight_144.ply"), os.path.join(stand, "happyStandRight_0.ply"),
                      "--html", wrong])
    street = os.path.join(DATA, "kitti_04")
    sweeps = sorted(os.path.join(street, f) for f in os.listdir(street) if f.endswith(".ply"))[:15]
    _run("register_scans", [*sweeps, "--out-poses", os.path.join(folder, "poses.conf"), "--html", scans, "--quiet"])
    return {"report_good_pair": (good, "side by side"), "report_likely_wrong": (wrong, None),
            "report_scan_set": (scans, None)}


def photograph(shots: dict, out: str) -> None:
    """A PNG ``out/<name>.png`` of each page of ``shots`` (see :func:`pages`), once its clouds are drawn."""
    from PIL import Image
    from playwright.sync_api import sync_playwright

    executable = os.environ.get("RPMNET_CHROMIUM") or next(
        (p for p in map(shutil.which, ("chromium", "chromium-browser", "google-chrome")) if p), None)
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=executable, args=ARGS)
        for name, (page_path, button) in shots.items():
            page = browser.new_page(viewport={"width": SIZE[0], "height": SIZE[1]})
            page.goto("file://" + os.path.abspath(page_path))
            page.wait_for_function("window.rpmnetViewer && window.rpmnetViewer.frames > 0", timeout=60000)
            if button:
                frames = page.evaluate("window.rpmnetViewer.frames")
                page.click(f"#views button:has-text('{button}')")
                page.wait_for_function(f"window.rpmnetViewer.frames > {frames}", timeout=60000)
            image = Image.open(io.BytesIO(page.screenshot())).convert("RGB")
            path = os.path.join(out, f"{name}.png")
            image.quantize(256, dither=Image.Dither.NONE).save(path, optimize=True)
            print(f"{path}: {os.path.getsize(path) / 1e3:.0f} KB")
            page.close()
        browser.close()


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", default=os.path.join(os.path.dirname(HERE), "docs"), help="folder of the PNGs")
    p.add_argument("--keep", default=None, help="folder to keep the HTML pages in (default: a temporary one)")
    args = p.parse_args()
    if args.keep:
        os.makedirs(args.keep, exist_ok=True)
        photograph(pages(args.keep), args.out)
        return
    with tempfile.TemporaryDirectory() as folder:
        photograph(pages(folder), args.out)


if __name__ == "__main__":
    main()
