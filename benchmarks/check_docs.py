"""Checks the numbers that README.md and docs/*.md state against their one source; exits 1 on a contradiction.

    python benchmarks/check_docs.py

Three checks, each printing ``FILE:LINE: what`` for every place that disagrees:

1. **Named numbers** (``NUMBERS`` below: one entry a number, with the results file or the command it comes from).
   Where a results file holds it, the value is read from that file; otherwise it is the value that command gave
   (the entry names the command and its commit). Each entry lists the phrasings (``claims``, regular
   expressions with a group ``v``) by which the docs state that number; every place in README.md and docs/*.md
   that matches one must state the same value, to the digits it shows (a doc may round: 22 for 22.4, not 77.9).
   A different value passes only as history: a commit other than the entry's own named in the 150 characters
   before it (``at 1db3d6a: 77.9 s``). An entry that no doc states fails too (its phrasing went stale, so it
   would check nothing).
2. **The real-scan tables**: every table row of README.md and docs/real_scans.md that names one of the benchmark's
   sets (Happy Buddha, TUM fr1_desk, KITTI 04, the national grid), in a column that names a method (``align``,
   Open3D's recipe, KISS-Matcher + small_gicp, ``align_scans``, Open3D multiway), against
   ``benchmarks/real_scans/results.jsonl``: success %, median rotation (°) and translation (mm / m), seconds,
   peak MB, each to the digits the cell shows.
3. **Links** between the pages: every ``(file.md#anchor)`` and ``(#anchor)`` in README.md and docs/*.md names an
   existing file and heading.

What it does not do: it finds a number only by the phrasings it knows; a new sentence stating a checked number in
new words needs its phrasing added to that entry's ``claims``. ``tests/docs_numbers_test.py`` runs it in the
default suite and shows it failing on planted contradictions.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
REAL_SCANS = os.path.join("benchmarks", "real_scans", "results.jsonl")
COMPARE_TORCH = os.path.join("benchmarks", "results_compare_torch.jsonl")
ROOM = os.path.join("benchmarks", "results_room_stations.jsonl")

NUM = r"\d+(?:,\d{3})*(?:\.\d+)?(?:e-?\d+)?"
RANGE = NUM + r"–" + NUM
SECONDS_LIST = r"(?P<v>" + NUM + r")(?: / " + NUM + r")* s\b"  # "22.4 s", "5.1 / 4.3 s": the first of the list
COMMIT = re.compile(r"\b(?=[0-9a-f]*\d)(?=[0-9a-f]*[a-f])[0-9a-f]{7,40}\b")


def _jsonl(root: str, path: str) -> list:
    with open(os.path.join(root, path)) as f:
        return [json.loads(line) for line in f if line.strip()]


def _real(root: str) -> dict:
    """``{(set, method): record}`` of the real-scan benchmark."""
    return {(r["set"], r["method"]): r for r in _jsonl(root, REAL_SCANS)}


def _torch_row(root: str, impl: str, task: str, points: int, batch: int) -> dict:
    """The row of ``benchmarks/compare_torch.py --malloc default``: ours in its own structure, the fused backward
    (the training CLI's default)."""
    for r in _jsonl(root, COMPARE_TORCH):
        if (r["impl"], r["task"], r["points"], r["batch"], r["malloc"]) == (impl, task, points, batch, "default") \
                and r.get("structure", "ours") == "ours" and r.get("variant", "fused") == "fused":
            return r
    raise KeyError((impl, task, points, batch))


def _range(values) -> str:
    return f"{min(values):.2f}–{max(values):.2f}"


def _pair_seconds(root: str, method: str) -> str:
    return _range([r["summary"]["seconds_per_pair"] for (s, m), r in _real(root).items() if m == method])


def _example_pair(root: str) -> dict:
    rec = _real(root)[("happy_stand", "rpmnet_jax")]
    return next(row for row in rec["rows"] if row["pair"] == ["happyStandRight_144", "happyStandRight_168"]
                and row["mode"] == "captured")


def _room(root: str, method: str) -> str:
    right = next(r for r in _jsonl(root, ROOM) if r["method"] == method)["summary"]["right"]
    return right.replace("/", " / ")


def numbers(root: str = ROOT) -> dict:
    """The named numbers: ``{name: {"value", "source", "claims", ["commit"]}}``; ``value`` a float, a string
    (``"0.02–0.03"``, ``"14 / 15"``) or a number as the source states it."""
    infer = "python benchmarks/compare_torch.py --malloc default --points 512 1024 2048 (2026-12-02), " + COMPARE_TORCH
    real = "python benchmarks/real_scans/run.py (bb83a76; its pairs again at 8f26daf), " + REAL_SCANS
    pair = _example_pair(root)
    return {
        # the network alone against the official code
        "network_inference_s": dict(
            value=_torch_row(root, "jax", "infer", 1024, 1)["seconds"], source=infer,
            claims=[r"1,024 points a cloud[^|\n]*\| (?P<v>" + NUM + r")",
                    r"\| infer \| 1024 \| 1 \| default \| " + NUM + r" \| \d+ \| (?P<v>" + NUM + r") \|"]),
        "official_inference_s": dict(
            value=_torch_row(root, "torch", "infer", 1024, 1)["seconds"], source=infer,
            claims=[r"1,024 points a cloud[^|\n]*\| " + NUM + r" s \| (?P<v>" + NUM + r") s \|",
                    r"official PyTorch (?P<v>" + NUM + r")\)",
                    r"\| infer \| 1024 \| 1 \| default \| (?P<v>" + NUM + r") \|"]),
        "training_step_s": dict(
            value=_torch_row(root, "jax", "train", 717, 8)["seconds"], source=infer,
            claims=[r"training step, batch 8, 717 points \| (?P<v>" + NUM + r") s",
                    r"fused backward \(CLI default\) \| 717 \| 8 \| default \| " + NUM + r" \| \d+ \| (?P<v>"
                    + NUM + r") \|"]),
        "official_training_step_s": dict(
            value=_torch_row(root, "torch", "train", 717, 8)["seconds"], source=infer,
            claims=[r"training step, batch 8, 717 points \| " + NUM + r" s \| (?P<v>" + NUM + r") s",
                    r"fused backward \(CLI default\) \| 717 \| 8 \| default \| (?P<v>" + NUM + r") \|"]),
        "parity_transforms": dict(
            value="5.4e-7", source="tests/parity_test.py on the official code's fixtures (docs/results.md, parity)",
            claims=[r"transforms (?:match the official code's to )?(?P<v>\d\.\de-\d+)"]),
        # the README's first commands, on the scans that come with the repository
        "example_pair_deg": dict(
            value=pair["rotation_deg"], source=real + " (happyStandRight_144 -> 168, as captured)",
            claims=[r"the pair is off by (?P<v>" + NUM + r")°"]),
        "example_pair_mm": dict(
            value=pair["translation"] * 1000, source=real + " (happyStandRight_144 -> 168, as captured)",
            claims=[r"the pair is off by " + NUM + r"° and (?P<v>" + NUM + r") mm"]),
        "example_scans_worst_deg": dict(
            value="0.93", commit="2d2a42e",
            source="README's rpmnet-register-scans command on the six happy_stand report scans, poses.conf "
                   "against $D/poses.conf (rpmnet_jax.evaluation.pose_errors), after 2d2a42e: 0.9264, 0.99 mm "
                   "(97a7ce0 in a fresh clone and venv: 0.9247; 0.93 was written at 07ca3c9)",
            claims=[r"the worst is off by (?P<v>" + NUM + r")°"]),
        "example_scans_worst_mm": dict(
            value="1.0", commit="07ca3c9", source="the same (RMS displacement of the scan's points)",
            claims=[r"the worst is off by " + NUM + r"° and (?P<v>" + NUM + r") mm"]),
        # the real-scan benchmark's ranges (its table cells: check 2)
        "real_pairs_align_s": dict(
            value=_pair_seconds(root, "rpmnet_jax"), source=real,
            claims=[r"a pair takes it (?P<v>" + RANGE + r") s",
                    r"real-scan benchmark's pairs[^|\n]*\| (?P<v>" + RANGE + r") \|"]),
        "real_pairs_open3d_s": dict(
            value=_pair_seconds(root, "open3d"), source=real,
            claims=[r"Open3D's recipe (?P<v>" + RANGE + r") s"]),
        "real_pairs_kiss_s": dict(
            value=_pair_seconds(root, "kiss_small_gicp"), source=real,
            claims=[r"KISS-Matcher \+ small_gicp (?P<v>" + RANGE + r") s"]),
        "room_pairs_right": dict(
            value=_room(root, "rpmnet_jax"), source="python benchmarks/room_stations.py (bb83a76), " + ROOM,
            claims=[r"station pairs (?P<v>\d+ / \d+) right"]),
        "room_stations_right": dict(
            value=_room(root, "rpmnet_jax_scans"), source="python benchmarks/room_stations.py (bb83a76), " + ROOM,
            claims=[r"the six stations (?P<v>\d+ / \d+) against"]),
        "room_stations_open3d_right": dict(
            value=_room(root, "open3d_multiway"), source="python benchmarks/room_stations.py (bb83a76), " + ROOM,
            claims=[r"Open3D multiway's (?P<v>\d+ / \d+)"]),
        # align's time per pair: what each measures (docs/performance.md, "Which time is which")
        "network_717_points_s": dict(
            value="0.19", source="benchmarks/align_time.py's stage times (docs/performance.md, what is still slow)",
            claims=[r"\((?P<v>" + NUM + r") s at 717 points", r"on a 717-point partial crop \| (?P<v>" + NUM + r")"]),
        "network_in_align_s": dict(
            value="0.23–0.25", source="benchmarks/align_time.py's stage times (docs/performance.md)",
            claims=[r"(?P<v>" + RANGE + r") s with the pipeline around it"]),
        "align_median_s": dict(
            value="0.020–0.030", commit="273feaf",
            source="python benchmarks/align_time.py --pairs 1000 on the public test files (273feaf), "
                   "docs/performance.md's table",
            claims=[r"a median (?P<v>" + RANGE + r") s", r"\): median \| (?P<v>" + RANGE + r") \|"]),
        "align_mean_partial_s": dict(
            value="0.038–0.050", commit="273feaf", source="the same",
            claims=[r"mean over the partial pairs[^|\n]*\| (?P<v>" + RANGE + r") \|"]),
        "align_full_scans_s": dict(
            value="0.25–0.30", commit="aec03da", source="python benchmarks/bunny_pairs_time.py --repeats 3 (aec03da)",
            claims=[r"worst 0\.37°\), (?P<v>" + RANGE + r") s a pair", r"the six bunny pairs\) \| (?P<v>" + RANGE
                    + r") \|"]),
        "align_eval_run_s": dict(
            value="0.13–0.81", commit="4cf9542",
            source="python -m experiments.eval ... --methods rpmnet,rpmnet_auto,ransac_icp,fgr_icp (4cf9542, beside "
                   "the test suite)",
            claims=[r"took (?P<v>" + RANGE + r") s a pair for `align`", r"before the speed work \| (?P<v>" + RANGE
                    + r") \|"]),
        # scan sets
        "bunny_60_scans_s": dict(
            value="22.4", commit="bd89eb0",
            source="python benchmarks/campaign_time.py DIR --units m --skip-open3d (bd89eb0; docs/results.md)",
            claims=[r"(?:60 bunny scans|bunny's 60 scans|bunny, 60 scans|60 simulated range scans)[^\n]{0,200}?"
                    + SECONDS_LIST]),
        "bunny_60_scans_pairs": dict(
            value="518", commit="bd89eb0", source="the same",
            claims=[r"(?P<v>\d+) in all for the bunny's 60 scans", r"(?P<v>\d+) pairs registered, 60 / 60"]),
        "bunny_10_scans_s": dict(
            value="5.1", commit="aec03da",
            source="python -m experiments.eval_scans --scans .../stanford_bunny --multiway --repeat 2 (aec03da)",
            claims=[r"10 bunny scans[^\n]{0,160}?" + SECONDS_LIST]),
        # knowing when it is wrong: the public test files' 6 wrong answers (v4)
        "ambiguous_flags_wrong": dict(
            value="5", source="python -m experiments.eval_doubt (the 1,220 public test pairs; docs/results.md, doubt)",
            claims=[r"(?P<v>\d+) are flagged `ambiguous`", r"`ambiguous` flags (?P<v>\d+) of the 6",
                    r"`ambiguous`: (?P<v>\d+) of 6", r"`ambiguous` flags (?P<v>\d+) \(near-symmetric"]),
        "likely_wrong_flags_wrong": dict(
            value="4", source="the same",
            claims=[r"and (?P<v>\d+) `likely_wrong`", r"`likely_wrong` flags (?P<v>\d+) of 6",
                    r"the same (?P<v>\d+) of the 6 wrong answers are flagged"]),
        # the report page
        "plotly_page_mb": dict(
            value="7.1", commit="07ca3c9", source="the command in docs/performance.md, the report page's size",
            claims=[r"Plotly's (?:self-contained )?page of (?:the same|such)[^\n]{0,80}?(?P<v>" + NUM + r") MB"]),
        "plotly_js_mb": dict(
            value="4.8", commit="07ca3c9", source="the same",
            claims=[r"(?P<v>" + NUM + r") MB of it plotly\.min\.js", r"plotly\.min\.js alone (?P<v>" + NUM + r") MB"]),
    }


# ---------------------------------------------------------------------------------------------------- reading


def doc_paths(root: str = ROOT) -> list:
    docs = os.path.join(root, "docs")
    return ["README.md"] + sorted(os.path.join("docs", f) for f in os.listdir(docs) if f.endswith(".md"))


def read_texts(root: str = ROOT) -> dict:
    texts = {}
    for path in doc_paths(root):
        with open(os.path.join(root, path), encoding="utf-8") as f:
            texts[path] = f.read()
    return texts


def logical_lines(text: str) -> list:
    """``[(first line number, text)]``: a paragraph or list item of prose joined into one line, a table row or a
    code line as it is; ``**`` dropped."""
    out, buf, start, code = [], [], 0, False
    def flush():
        if buf:
            out.append((start, " ".join(buf)))
            buf.clear()
    for i, line in enumerate(text.replace("**", "").split("\n"), 1):
        stripped = line.strip()
        if stripped.startswith("```"):
            flush()
            code = not code
            continue
        if code or stripped.startswith("|") or stripped.startswith("#") or not stripped:
            flush()
            if stripped:
                out.append((i, line))
            continue
        if re.match(r"\s*(?:[-*]|\d+\.)\s", line):  # a new list item
            flush()
        if not buf:
            start = i
        buf.append(stripped)
    flush()
    return out


def _decimals(text: str) -> int:
    text = text.replace(",", "")
    if "e" in text.lower():
        mantissa, exp = text.lower().split("e")
        return _decimals(mantissa) - int(exp)
    return len(text.split(".")[1]) if "." in text else 0


def _parse(text: str) -> float:
    return float(text.replace(",", ""))


def agrees(stated: str, value) -> bool:
    """``stated`` (as a doc prints it) agrees with ``value`` to the digits ``stated`` shows."""
    stated = stated.strip()
    if isinstance(value, str) and "/" in value:
        return stated.replace(" ", "") == value.replace(" ", "")
    if isinstance(value, str) and "–" in value:
        parts, want = stated.split("–"), value.split("–")
        return len(parts) == 2 and all(agrees(p, w) for p, w in zip(parts, want))
    if "–" in stated:
        return False
    truth = _parse(value) if isinstance(value, str) else float(value)
    return abs(_parse(stated) - truth) <= 0.5 * 10.0 ** -_decimals(stated) * (1 + 1e-9) + 1e-12


# ---------------------------------------------------------------------------------------------------- checks


def check_numbers(texts: dict, root: str = ROOT) -> tuple:
    errors, places = [], 0
    for name, entry in numbers(root).items():
        found = 0
        for path, text in texts.items():
            for lineno, line in logical_lines(text):
                for claim in entry["claims"]:
                    for m in re.finditer(claim, line):
                        found += 1
                        stated = m.group("v")
                        if agrees(stated, entry["value"]):
                            continue
                        before = line[max(0, m.start("v") - 150):m.start("v")]
                        others = [c for c in COMMIT.findall(before) if c != entry.get("commit")]
                        if others:
                            continue  # history: the value of another commit, which it names
                        shown = entry["value"] if isinstance(entry["value"], str) else f"{entry['value']:.6g}"
                        errors.append(f"{path}:{lineno}: {name}: states {stated}, its source says {shown} "
                                      f"({entry['source']})")
        if not found:
            errors.append(f"(none): {name}: stated nowhere in README.md or docs/*.md by the phrasings it knows "
                          f"(update its claims in benchmarks/check_docs.py)")
        places += found
    return errors, places


SETS = [("kitti_04@grid", r"national grid|@grid|georeferenced"), ("kitti_04", r"kitti"),
        ("happy_stand", r"happy|buddha"), ("tum_fr1_desk", r"tum|desk")]
METHODS = [("rpmnet_jax_scans", r"align_scans"), ("open3d_multiway", r"multiway"),
           ("rpmnet_jax", r"`align`|rpmnet_jax"), ("kiss_small_gicp", r"kiss"), ("open3d", r"open3d")]
REAL_TABLE_DOCS = ("README.md", os.path.join("docs", "real_scans.md"))


def _cells(row: str) -> list:
    return [c.strip() for c in row.strip().strip("|").split("|")]


def _cell_values(cell: str, header: str, record: dict) -> list:
    """``[(stated, true value, what)]`` of one table cell."""
    s, out = record["summary"], []
    seconds = s.get("seconds_per_pair", s.get("seconds"))
    m = re.match(r"^(" + NUM + r")$", cell)
    if m:  # a bare number: the header says what
        if "second" in header:
            return [(m.group(1), seconds, "seconds")]
        if "right" in header:
            return [(m.group(1), s["success"] * 100, "success %")]
        return []
    measures = (  # (where, pattern, value, label): the success share is read before its parenthesis
        (cell.split("(")[0], r"%", s["success"] * 100, "success %"),
        (cell, r"°", s["median_rotation_deg"], "median rotation °"),
        (cell, r" mm\b", s["median_translation"] * 1000, "median translation mm"),
        (cell, r" m\b", s["median_translation"], "median translation m"),
        (cell, r" s(?:/pair)?\b", seconds, "seconds"),
        (cell, r" MB", record["peak_rss_mb"], "peak MB"))
    for text, unit, value, label in measures:
        m = re.search(r"(" + NUM + r")" + unit, text)
        if m:
            out.append((m.group(1), value, label))
    return out


def check_real_tables(texts: dict, root: str = ROOT) -> tuple:
    real, errors, cells = _real(root), [], 0
    for path in REAL_TABLE_DOCS:
        header = None
        for lineno, line in enumerate(texts.get(path, "").replace("**", "").split("\n"), 1):
            if not line.startswith("|"):
                header = None
                continue
            row = _cells(line)
            if header is None:
                header = row
                continue
            if set(line) <= set("|-: "):
                continue
            name = next((s for s, pat in SETS if re.search(pat, row[0], re.I)), None)
            if name is None:
                continue
            for head, cell in zip(header[1:], row[1:]):
                method = next((m for m, pat in METHODS if re.search(pat, head, re.I)), None)
                if method is None or (name, method) not in real:
                    continue
                record = real[(name, method)]
                for stated, truth, what in _cell_values(cell, header[0].lower(), record):
                    cells += 1
                    if not agrees(stated, truth):
                        errors.append(f"{path}:{lineno}: {name}, {method}, {what}: states {stated}, {REAL_SCANS} "
                                      f"says {truth:.6g}")
                if "placed right by both" in header[0] and record["summary"]["success"] != 1.0:
                    errors.append(f"{path}:{lineno}: {name}, {method}: the header says every scan is placed right, "
                                  f"{REAL_SCANS} says {record['summary']['success']:.0%}")
    return errors, cells


def _slug(heading: str) -> str:
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower().replace("`", ""))
    return text.replace(" ", "-")


def check_links(texts: dict, root: str = ROOT) -> tuple:
    anchors = {path: {_slug(line.lstrip("#")) for line in text.split("\n") if re.match(r"#+ ", line)}
               for path, text in texts.items()}
    errors, links = [], 0
    for path, text in texts.items():
        for lineno, line in enumerate(text.split("\n"), 1):
            for target, anchor in re.findall(r"\]\(([^()\s#]*\.md|)#([^()\s]+)\)", line):
                links += 1
                doc = os.path.normpath(os.path.join(os.path.dirname(path), target)) if target else path
                if doc not in anchors:
                    if not os.path.exists(os.path.join(root, doc)):
                        errors.append(f"{path}:{lineno}: link to {target}#{anchor}: no such file")
                    continue
                if anchor not in anchors[doc]:
                    errors.append(f"{path}:{lineno}: link to {target or path}#{anchor}: no such heading")
    return errors, links


def check(texts: dict | None = None, root: str = ROOT) -> list:
    """Every contradiction found, as ``FILE:LINE: what`` lines (empty: none)."""
    texts = read_texts(root) if texts is None else texts
    errors = []
    for run in (check_numbers, check_real_tables, check_links):
        errors += run(texts, root)[0]
    return errors


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--root", default=ROOT, help="the repository to check (default: this one)")
    root = p.parse_args(argv).root
    texts = read_texts(root)
    (e1, n1), (e2, n2), (e3, n3) = (run(texts, root) for run in (check_numbers, check_real_tables, check_links))
    for line in e1 + e2 + e3:
        print(line)
    print(f"{len(numbers(root))} named numbers in {n1} places, {n2} real-scan table values, {n3} links: "
          f"{len(e1 + e2 + e3)} contradiction(s)", file=sys.stderr)
    return 1 if e1 + e2 + e3 else 0


if __name__ == "__main__":
    sys.exit(main())
