"""HTML reports: a self-contained page (no network), the points it holds (finite rows, capped, deterministic,
within a quantum of the input), the numbers escaped; opened in headless Chromium: no script error, the clouds
drawn in their colours, the numbers shown, a drag and the wheel change the picture."""

import base64
import json
import os
import re
import shutil

import numpy as np
import pytest

from conftest import unavailable
from rpmnet_jax.report import pages


def _cloud(seed, n=500):
    rng = np.random.default_rng(seed)
    return rng.normal(size=(n, 3)) * [0.1, 0.05, 0.02] + [5e5, 4e6, 100.0]  # georeferenced: UTM-like offsets


def _pair(tmp_path, numbers=None, **kw):
    src, ref = _cloud(0), _cloud(1)
    aligned = src + [0.02, 0.0, 0.0]
    path = tmp_path / "r.html"
    pages.pair_report(str(path), src, ref, aligned, numbers or {"fitness": 0.8731}, **kw)
    return path, (src, ref, aligned)


def _data(path):
    text = path.read_text(encoding="utf-8")
    found = re.search(r'<script type="application/json" id="rpmnet-data">(.*?)</script>', text, re.S)
    return json.loads(found.group(1))


def _points(cloud, extent):
    q = np.frombuffer(base64.b64decode(cloud["points"]), "<u2").reshape(-1, 3)
    return q / 65535.0 * np.asarray(extent)  # from the low corner of the box


def test_check_path_wants_html():
    pages.check_path("a/report.html")
    pages.check_path("R.HTM")
    with pytest.raises(ValueError, match=r"--html must name a \.html file, got r\.png"):
        pages.check_path("r.png")


def test_page_is_self_contained_and_shows_the_numbers(tmp_path):
    path, _ = _pair(tmp_path, {"fitness": 0.8731, "transform": np.eye(4), "start": "<b>x</b>",
                               "candidates": [{"start": "classical", "fitness": 0.8731}]})
    text = path.read_text(encoding="utf-8")
    assert "0.8731" in text and "&lt;b&gt;x&lt;/b&gt;" in text and "<b>x</b>" not in text
    assert not re.search(r"(src|href)\s*=|https?://|@import", text)  # no file, script or style fetched
    assert "@@" not in text and "rpmnetViewer" in text


def test_points_are_finite_capped_deterministic_and_within_a_quantum(tmp_path):
    path, (src, ref, aligned) = _pair(tmp_path)
    data = _data(path)
    assert [c["name"] for c in data["clouds"]] == ["source", "reference", "aligned source"]
    lo = np.min([x.min(0) for x in (src, ref, aligned)], axis=0)
    for cloud, x in zip(data["clouds"], (src, ref, aligned)):
        assert cloud["drawn"] == cloud["rows"] == 500
        np.testing.assert_allclose(_points(cloud, data["extent"]) + lo, x, rtol=0,
                                   atol=0.51 * max(data["extent"]) / 65535)

    src[::7] = np.nan  # NaN rows of the source are NaN in the aligned source too
    aligned[::7] = np.nan
    ref[3] = np.inf
    for name in ("a.html", "b.html"):
        pages.pair_report(str(tmp_path / name), src, ref, aligned, {}, max_points=300)
    data = _data(tmp_path / "a.html")
    assert (tmp_path / "a.html").read_bytes() == (tmp_path / "b.html").read_bytes()
    assert [(c["rows"], c["drawn"]) for c in data["clouds"]] == [(428, 300), (499, 300), (428, 300)]
    moved = _points(data["clouds"][2], data["extent"]) - _points(data["clouds"][0], data["extent"])
    np.testing.assert_allclose(moved, np.tile([0.02, 0, 0], (300, 1)), atol=2 * max(data["extent"]) / 65535)


def test_scans_page_leaves_out_missing_scans_and_shares_the_points(tmp_path):
    path = tmp_path / "s.html"
    pages.scans_report(str(path), [_cloud(0), None, _cloud(2, 900)], ["a.ply", "b.ply", "c</script>.ply"],
                       {"edges": 2, "poses": {"a.ply": np.eye(4)}}, max_total=1200)
    data = _data(path)
    assert [(c["name"], c["drawn"]) for c in data["clouds"]] == [("a.ply", 400), ("b.ply", 0),
                                                                  ("c</script>.ply", 400)]
    assert data["views"] == [{"title": "registered scans", "clouds": [0, 1, 2],
                              "centre": data["views"][0]["centre"]}]
    assert path.read_text(encoding="utf-8").count("</script>") == 2  # the data's own is escaped


# --- in a browser ----------------------------------------------------------------------------------------------

ARGS = ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader"]  # WebGL without a GPU
PIXELS = """() => {  // pixels of the WebGL canvas by dominant channel, rows with a coloured one, a checksum
  const c = document.getElementById("view"), t = document.createElement("canvas");
  t.width = c.width; t.height = c.height;
  const g = t.getContext("2d"); g.drawImage(c, 0, 0);
  const d = g.getImageData(0, 0, t.width, t.height).data, n = {red: 0, green: 0, blue: 0, other: 0};
  const rows = new Set();
  let sum = 0;
  for (let i = 0; i < d.length; i += 4) {
    const r = d[i], gr = d[i + 1], b = d[i + 2];
    sum = (sum * 31 + r + 7 * gr + 13 * b) % 1000000007;
    if (r > gr + 40 && r > b + 40) n.red++; else if (gr > r + 40 && gr > b + 25) n.green++;
    else if (b > r + 40 && b > gr + 25) n.blue++; else { n.other++; continue; }
    rows.add(Math.floor(i / 4 / t.width));
  }
  n.sum = sum;
  n.rows = rows.size;
  return n;
}"""


@pytest.fixture(scope="module")
def browser():
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        unavailable("playwright is not installed (pip install playwright)")
    executable = os.environ.get("RPMNET_CHROMIUM") or next(
        (p for p in map(shutil.which, ("chromium", "chromium-browser", "google-chrome")) if p), None)
    with sync_playwright() as p:
        try:
            browser = p.chromium.launch(executable_path=executable, args=ARGS)
        except Exception as e:  # no browser at all: playwright's message says how to get one
            unavailable(f"no Chromium to run (apt-get install chromium, or set RPMNET_CHROMIUM): {e}".splitlines()[0])
        yield browser
        browser.close()


def _open(browser, path):
    page = browser.new_page(viewport={"width": 1000, "height": 600})
    errors = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
    page.goto(path.as_uri())
    page.wait_for_function("window.rpmnetViewer && (window.rpmnetViewer.frames > 0 || window.rpmnetViewer.error)",
                           timeout=20000)
    assert page.evaluate("window.rpmnetViewer.error") is None
    return page, errors


def _settle(page, frames):
    page.wait_for_function(f"window.rpmnetViewer.frames > {frames}", timeout=10000)
    return page.evaluate(PIXELS)


def test_pair_page_draws_the_clouds_and_turns(tmp_path, browser):
    path, _ = _pair(tmp_path)
    page, errors = _open(browser, path)
    after = page.evaluate(PIXELS)
    assert after["green"] > 200 and after["blue"] > 200 and after["red"] == 0, after  # aligned on reference
    assert "0.8731" in page.inner_text("aside")
    frames = page.evaluate("window.rpmnetViewer.frames")
    page.click("#views button:has-text('side by side')")
    both = _settle(page, frames)
    assert both["red"] > 200 and both["green"] > 200 and both["blue"] > 200, both
    assert page.inner_text("#titles").split() == ["after", "before"]

    frames = page.evaluate("window.rpmnetViewer.frames")
    page.mouse.move(300, 300)
    page.mouse.down()
    page.mouse.move(420, 250, steps=5)
    page.mouse.up()
    turned = _settle(page, frames)
    assert turned["sum"] != both["sum"]
    frames = page.evaluate("window.rpmnetViewer.frames")
    page.mouse.wheel(0, -400)  # zoom in: the clouds span more rows of the canvas
    zoomed = _settle(page, frames)
    assert zoomed["rows"] > 1.3 * turned["rows"], (zoomed, turned)

    frames = page.evaluate("window.rpmnetViewer.frames")
    page.click("#legend label:has-text('reference') input")  # hidden: no blue left
    assert _settle(page, frames)["blue"] == 0
    assert errors == []
    page.close()


def test_scans_page_colours_each_scan(tmp_path, browser):
    path = tmp_path / "s.html"
    # tab10's first three colours: blue, orange (red-dominant), green
    pages.scans_report(str(path), [_cloud(0), _cloud(1) + [0.3, 0, 0], _cloud(2) - [0.3, 0, 0]],
                       ["a", "b", "c"], {"edges": 3})
    page, errors = _open(browser, path)
    seen = page.evaluate(PIXELS)
    assert seen["blue"] > 200 and seen["red"] > 200 and seen["green"] > 200, seen
    assert "edges" in page.inner_text("aside") and errors == []
    page.close()
