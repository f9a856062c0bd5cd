"""HTML reports: a self-contained page (no network), the points it holds (finite rows, capped, deterministic,
within a quantum of the input), the numbers escaped, the banner, the views (*before* then *after*, each framed on
its sphere); opened in headless Chromium: no script error, the clouds drawn in their colours, before left of after,
the numbers shown, a drag and the wheel change the picture, the banner on top, a LiDAR cloud inside its canvas,
and a 15-scan page whose legend leaves the middle of the canvas free and whose tables fit their panel."""

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


def test_banner_tops_the_page_only_when_there_is_something_to_say(tmp_path):
    path, _ = _pair(tmp_path, alerts=["Likely wrong: p_wrong 0.985 <check>"])
    text = path.read_text(encoding="utf-8")
    assert text.index("id='alerts'") < text.index("<main>")
    assert "Likely wrong: p_wrong 0.985 &lt;check&gt;" in text and "<title>⚠ rpmnet-register</title>" in text
    path, _ = _pair(tmp_path)
    text = path.read_text(encoding="utf-8")
    assert "id='alerts'" not in text and "<title>rpmnet-register</title>" in text


def test_views_are_before_then_after_each_framed_on_its_sphere(tmp_path):
    aligned, ref = _cloud(0), _cloud(1)
    src = aligned + [5.0, 0.0, 0.0]  # the source starts far from the reference: *before* spans more
    pages.pair_report(str(tmp_path / "r.html"), src, ref, aligned, {})
    data = _data(tmp_path / "r.html")
    assert [v["title"] for v in data["views"]] == ["before", "after"] and data["first"] == 1  # opens on *after*
    assert [v["clouds"] for v in data["views"]] == [[0, 1], [2, 1]]
    for view, shown in zip(data["views"], ([src, ref], [aligned, ref])):
        pts = np.concatenate(shown)
        centre = (pts.min(0) + pts.max(0)) / 2
        np.testing.assert_allclose(view["radius"], np.linalg.norm(pts - centre, axis=1).max(), rtol=1e-9)
    assert data["views"][0]["radius"] > 5 * data["views"][1]["radius"]


def test_a_flat_cloud_opens_with_z_up(tmp_path):
    flat = np.random.default_rng(0).uniform(-1, 1, (200, 3)) * [40, 40, 2]  # a street seen by a LiDAR
    for cloud, up in ((flat, "z"), (flat[:, [0, 2, 1]], "y")):
        pages.scans_report(str(tmp_path / "s.html"), [cloud], ["a"], {})
        assert _data(tmp_path / "s.html")["up"] == up


def test_scans_page_leaves_out_missing_scans_and_shares_the_points(tmp_path):
    path = tmp_path / "s.html"
    pages.scans_report(str(path), [_cloud(0), None, _cloud(2, 900)], ["a.ply", "b.ply", "c</script>.ply"],
                       {"edges": 2, "poses": {"a.ply": np.eye(4)}}, max_total=1200)
    data = _data(path)
    assert [(c["name"], c["drawn"]) for c in data["clouds"]] == [("a.ply", 400), ("b.ply", 0),
                                                                  ("c</script>.ply", 400)]
    assert [(v["title"], v["clouds"]) for v in data["views"]] == [("registered scans", [0, 1, 2])]
    text = path.read_text(encoding="utf-8")
    assert text.count("</script>") == text.count("<script") == 3  # the data's own is escaped


# --- in a browser ----------------------------------------------------------------------------------------------

ARGS = ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader"]  # WebGL without a GPU
PIXELS = """() => {  // pixels of the WebGL canvas by dominant channel (all, left half, right half), rows with a
  // coloured one, the box of the coloured ones [left, top, right, bottom], the canvas's size, a checksum
  const c = document.getElementById("view"), t = document.createElement("canvas");
  t.width = c.width; t.height = c.height;
  const g = t.getContext("2d"); g.drawImage(c, 0, 0);
  const d = g.getImageData(0, 0, t.width, t.height).data, n = {red: 0, green: 0, blue: 0, other: 0};
  const half = [{red: 0, green: 0, blue: 0}, {red: 0, green: 0, blue: 0}], box = [t.width, t.height, -1, -1];
  const rows = new Set();
  let sum = 0;
  for (let i = 0; i < d.length; i += 4) {
    const r = d[i], gr = d[i + 1], b = d[i + 2], x = (i / 4) % t.width, y = Math.floor(i / 4 / t.width);
    sum = (sum * 31 + r + 7 * gr + 13 * b) % 1000000007;
    let k;
    if (r > gr + 40 && r > b + 40) k = "red"; else if (gr > r + 40 && gr > b + 25) k = "green";
    else if (b > r + 40 && b > gr + 25) k = "blue"; else { n.other++; continue; }
    n[k]++;
    half[x < t.width / 2 ? 0 : 1][k]++;
    rows.add(y);
    box[0] = Math.min(box[0], x); box[1] = Math.min(box[1], y);
    box[2] = Math.max(box[2], x); box[3] = Math.max(box[3], y);
  }
  n.sum = sum;
  n.rows = rows.size;
  n.left = half[0];
  n.right = half[1];
  n.box = box;
  n.size = [t.width, t.height];
  return n;
}"""
LAYOUT = """() => {  // the canvas, whether the legend covers its middle (the middle half across and down), what covers
  // it at all, the banner's box, and any panel, table or banner wider than the room it has
  const box = e => e.getBoundingClientRect(), c = box(document.getElementById("view"));
  const meets = (a, b) => a.left < b.right && b.left < a.right && a.top < b.bottom && b.top < a.bottom;
  const middle = {left: c.left + c.width / 4, right: c.right - c.width / 4,
                  top: c.top + c.height / 4, bottom: c.bottom - c.height / 4};
  const aside = document.querySelector("aside"), banner = document.getElementById("alerts");
  const wide = [aside, banner].concat([...aside.querySelectorAll("table, pre")]).filter(e => e &&
    (e.scrollWidth > e.clientWidth || box(e).right > box(aside).right));
  return {canvas: [c.left, c.top, c.width, c.height],
          legendOnMiddle: meets(box(document.getElementById("legend")), middle),
          covering: ["legend", "controls", "titles", "hint"].filter(id => meets(box(document.getElementById(id)), c)),
          banner: banner && [box(banner).left, box(banner).top, box(banner).width, box(banner).height],
          wide: wide.map(e => e.tagName + " " + e.scrollWidth + ">" + e.clientWidth)};
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


def _open(browser, path, size=(1000, 600)):
    page = browser.new_page(viewport={"width": size[0], "height": size[1]})
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
    assert page.inner_text("#titles").split() == ["before", "after"]
    assert both["left"]["red"] > 200 and both["left"]["green"] == 0, both  # before (source) left of after
    assert both["right"]["green"] > 200 and both["right"]["red"] == 0, both

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


def test_banner_is_the_first_thing_on_the_page(tmp_path, browser):
    path, _ = _pair(tmp_path, alerts=["Likely wrong: p_wrong 0.985 (the calibrated probability that the rotation is "
                                      "off). Check the clouds before using this transform."])
    page, errors = _open(browser, path)
    layout = page.evaluate(LAYOUT)
    assert layout["banner"][:3] == [0, 0, 1000] and layout["banner"][3] > 30, layout
    assert layout["canvas"][1] >= layout["banner"][3], layout  # the viewer starts below it
    assert "Likely wrong: p_wrong 0.985" in page.inner_text("#alerts") and layout["wide"] == [], layout
    assert errors == []
    page.close()


def _street(seed, n=4000):
    """A LiDAR sweep's kind of cloud: z up, 80 m across, a few metres high, in a national grid."""
    rng = np.random.default_rng(seed)
    return rng.uniform(-1, 1, (n, 3)) * [40, 40, 1.5] + [5e5, 4e6, 100.0]


def test_a_lidar_cloud_fits_its_view(tmp_path, browser):
    """Nothing drawn touches the canvas's edges or lies under the buttons; the cloud fills much of it."""
    path = tmp_path / "s.html"
    pages.scans_report(str(path), [_street(0), _street(1) + [3.0, 0, 0]], ["a", "b"], {})
    page, errors = _open(browser, path)
    seen, layout = page.evaluate(PIXELS), page.evaluate(LAYOUT)
    (left, top, right, bottom), (w, h) = seen["box"], seen["size"]
    assert left > 2 and top > 2 and right < w - 3 and bottom < h - 3, seen
    assert max((right - left) / w, (bottom - top) / h) > 0.6, seen
    assert layout["covering"] == [], layout
    for size in ((1000, 300), (500, 900)):  # a wide and a tall canvas
        frames = page.evaluate("window.rpmnetViewer.frames")
        page.set_viewport_size({"width": size[0], "height": size[1]})
        seen = _settle(page, frames)
        (left, top, right, bottom), (w, h) = seen["box"], seen["size"]
        assert left > 2 and top > 2 and right < w - 3 and bottom < h - 3, (size, seen)
    assert errors == []
    page.close()


def _fifteen_scans(tmp_path):
    names = [f"kitti04_{2 * i:06d}_velodyne_sweep_cleaned.ply" for i in range(14)]
    names.append("ScanPosition014SingleScan220613134507MonitorHighRes.ply")  # no place to break a line
    clouds = [_street(i, 2000) + [4.0 * i, 0, 0] for i in range(15)]
    poses = {name: np.array([[1, 0, 0, 123.456789 * i], [0, 1, 0, -98.7654321], [0, 0, 1, 1.5], [0, 0, 0, 1.0]])
             for i, name in enumerate(names)}

    def edges(pairs):
        return [{"source": names[a], "target": names[b], "stage": "classical", "fitness": 0.61234,
                 "inlier RMSE": 0.0731234} for a, b in pairs]
    numbers = {"scans placed": "15 of 15", "left out (overlap none of the placed)": "none", "edges": 24,
               "rejected edges": 2, "voxel": 0.3, "correspondence distance": 0.9, "time (s)": 41.2345,
               "scans": [{"scan": n, "points": 30000, "rotation (deg)": 12.3456 * i, "translation": 123.456789 * i,
                          "edges": 3} for i, n in enumerate(names)],
               "poses (scan onto the first scan's frame)": poses,
               "pose-graph edges": edges([(i, i + 1) for i in range(14)] + [(i, i + 2) for i in range(10)]),
               "rejected": edges([(0, 7), (3, 12)])}
    path = tmp_path / "s.html"
    pages.scans_report(str(path), clouds, names, numbers,
                       alerts=["Likely wrong poses (2): " + ", ".join(names[12:14]) + ": placed by a registration "
                               "flagged likely wrong; check them."])
    return path


@pytest.mark.parametrize("size", [(1400, 900), (1000, 700)])
def test_fifteen_scans_legend_leaves_the_middle_free_and_tables_fit(tmp_path, browser, size):
    page, errors = _open(browser, _fifteen_scans(tmp_path), size)
    layout = page.evaluate(LAYOUT)
    assert not layout["legendOnMiddle"] and layout["wide"] == [], layout
    assert layout["canvas"][2] > 0.5 * size[0] and layout["canvas"][3] > 0.45 * size[1], layout  # room to look
    seen = page.evaluate(PIXELS)
    assert seen["other"] < seen["size"][0] * seen["size"][1] and seen["box"][2] > 0, seen  # the scans are drawn
    assert errors == []
    page.close()
