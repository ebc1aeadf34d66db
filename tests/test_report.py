"""The run report: content, escaping, and a check in headless Chromium that it loads cleanly."""

from __future__ import annotations

import csv
import io
import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from meshdenoise.render import render_comparison
from meshdenoise.report import write_report
from meshdenoise.shapes import icosphere

# Put first in <head>: records console errors, script errors and failed resource loads, then after
# load every <img> that did not decode and every element whose content is wider than its box (a table
# scrolling sideways inside its own box), with the page's size and where each picture lies, into
# <pre id="page-check"> for --dump-dom to show.
CHECKER = """<script>
(function () {
  var problems = [];
  var original = console.error;
  console.error = function () { problems.push("console.error: " + Array.prototype.join.call(arguments, " "));
                                original.apply(console, arguments); };
  window.addEventListener("error", function (e) {
    var t = e.target || {};
    problems.push(t.tagName ? ("failed to load " + t.tagName + " " + (t.src || t.href)) : ("script error: " + e.message));
  }, true);
  window.addEventListener("load", function () {
    var imgs = Array.prototype.slice.call(document.images);
    imgs.forEach(function (img) {
      if (!img.complete || img.naturalWidth === 0) problems.push("image not loaded: " + img.src);
    });
    Array.prototype.forEach.call(document.querySelectorAll("body *"), function (el) {
      if (el.clientWidth > 0 && el.scrollWidth > el.clientWidth + 1 && getComputedStyle(el).overflowX !== "visible")
        problems.push("scrolls sideways: " + el.tagName + " " + el.scrollWidth + " px in " + el.clientWidth);
    });
    var boxes = imgs.map(function (img) {
      var r = img.getBoundingClientRect();  // the picture inside the border, in page pixels
      return {src: img.getAttribute("src").slice(0, 200), x: r.left + window.scrollX + img.clientLeft,
              y: r.top + window.scrollY + img.clientTop, w: img.clientWidth, h: img.clientHeight,
              natural: [img.naturalWidth, img.naturalHeight]};
    });
    var pre = document.createElement("pre"); pre.id = "page-check";
    pre.textContent = JSON.stringify({images: imgs.length, problems: problems, boxes: boxes,
                                      width: document.documentElement.scrollWidth,
                                      height: document.documentElement.scrollHeight, viewport: window.innerWidth});
    document.body.appendChild(pre);
  });
})();
</script>"""


WINDOW = (1280, 900)  # the window the report must fit without horizontal overflow


def _chromium() -> str:
    exe = shutil.which("chromium") or shutil.which("chromium-browser")
    if exe is None:
        pytest.fail("headless Chromium is needed to check the report: install the Debian package 'chromium' "
                    "(scripts/install-system-deps.sh does, and `make test` runs it)")
    return exe


def _chromium_cmd(tmp_path, height=WINDOW[1]) -> list[str]:
    return [_chromium(), "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
            "--disable-background-networking", "--disable-component-update", "--disable-sync", "--hide-scrollbars",
            "--force-device-scale-factor=1", f"--window-size={WINDOW[0]},{height}",
            f"--user-data-dir={tmp_path / 'chromium-profile'}", "--virtual-time-budget=10000"]


def chromium_check(page, tmp_path, boxes=False) -> dict:
    """Open a copy of ``page`` (same folder, so relative links hold) with the checker in headless Chromium.

    Returns the number of images, the problems found (including any element scrolling sideways) and
    the page's scroll width (px); with ``boxes`` also the page's height and where each picture lies.
    """
    probe = page.with_name(".check-" + page.name)
    probe.write_text(page.read_text(encoding="utf-8").replace("<head>", "<head>" + CHECKER, 1), encoding="utf-8")
    for _ in range(2):  # a browser killed by a signal (seen once: exit -11 in CI) says nothing of the page: once more
        proc = subprocess.run(_chromium_cmd(tmp_path) + ["--dump-dom", probe.resolve().as_uri()],
                              capture_output=True, text=True, timeout=120)
        found = re.search(r'<pre id="page-check">(.*?)</pre>', proc.stdout, re.S)
        if found or proc.returncode >= 0:
            break
    probe.unlink()
    assert found, f"Chromium gave no page check (exit {proc.returncode}): {proc.stderr[-2000:]}"
    import html

    result = json.loads(html.unescape(found.group(1)))
    assert result.pop("viewport") == WINDOW[0]  # the window really was 1280 px wide
    if not boxes:
        del result["boxes"], result["height"]
    return result


def screenshot(page, png, tmp_path, height=WINDOW[1]) -> tuple[int, int]:
    """A screenshot of ``page`` in a window 1280 pixels wide (``height`` tall: the whole page when it is the
    page's height); returns the PNG's (width, height) from its header."""
    import struct

    proc = subprocess.run(_chromium_cmd(tmp_path, height) + [f"--screenshot={png}", page.resolve().as_uri()],
                          capture_output=True, text=True, timeout=120)
    assert png.is_file(), f"no screenshot (exit {proc.returncode}): {proc.stderr[-2000:]}"
    head = png.read_bytes()[:24]
    assert head[:8] == b"\x89PNG\r\n\x1a\n"
    return struct.unpack(">II", head[16:24])


@pytest.fixture
def run_dir(tmp_path):
    """A run folder like a pipeline's: results CSV, a reproduction JSON, renders (odd names), a plot, a mesh."""
    run = tmp_path / "run 1"
    (run / "renders").mkdir(parents=True)
    with (run / "results.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["method", "params", "snr_db"])
        w.writerow(["sobolev", "mu=1.0", "31.25"])
        w.writerow(["<script>alert(1)</script>", "a&b \"q\"", "12.5"])
    (run / "results.json").write_text(json.dumps(
        {"paper": "Vaillant-Tenzer 2022", "rows": [{"mesh": "elephant", "method": "heat", "snr": {"db": 20.5}}]}))
    V, F = icosphere(2)
    render_comparison([(V * 1.05, F), (V * 1.01, F)], run / "renders" / "before after #1.png", reference=(V, F),
                      size=(48, 48), backend="matplotlib")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(2, 2))
    ax.plot([1, 2, 3], [20, 25, 31])
    fig.savefig(run / "snr é.png")
    plt.close(fig)
    (run / "sobolev.ply").write_bytes(b"ply\n")
    return run


def test_report_tables_are_escaped_and_complete(run_dir):
    page = write_report(run_dir)
    text = page.read_text(encoding="utf-8")
    assert "<wbr>" in text  # break opportunities in long names, not text: compare without them
    text = text.replace("<wbr>", "")
    assert page == run_dir / "report.html"
    assert "<script>alert(1)</script>" not in text and "&lt;script&gt;alert(1)&lt;/script&gt;" in text
    assert "a&amp;b &quot;q&quot;" in text
    assert '<td class="num">31.25</td>' in text and '<td class="nw">sobolev</td>' in text
    assert "<th>snr.db</th>" in text and '<td class="num">20.5</td>' in text  # nested JSON flattened
    assert "<td>Vaillant-Tenzer 2022</td>" in text  # 21 characters: may wrap
    assert 'src="renders/before%20after%20%231.png"' in text and 'src="snr%20%C3%A9.png"' in text
    assert 'href="sobolev.ply"' in text
    assert "<script" not in text.replace("&lt;script", "")  # the page itself runs no script


@pytest.mark.parametrize("value, shown", [
    (44.07087922224201, "44.07"), (0.10840000000000001, "0.1084"), (28088, "28088"), (1e-07, "1e-07"),
    (-3.14159e-5, "-3.142e-05"), (123456.789, "123457"), (0.0, "0"), (float("inf"), "inf"), (True, "True"),
    ("12.30", "12.3"), ("mu=1", "mu=1"), ("", ""), ("7", "7")])
def test_format_number_keeps_four_significant_digits(value, shown):
    from meshdenoise.report import format_number

    assert format_number(value) == shown
    number = value if isinstance(value, (int, float)) and not isinstance(value, bool) else None
    if number is not None and number != 0 and abs(number) < 1e4 and np.isfinite(number):
        assert abs(float(shown) - number) <= 0.5e-3 * abs(number)  # within half a unit of the 4th digit


def _run(pipeline, out):
    """Run the pipeline file through `meshdenoise run --serial`; (its output folder, the file)."""
    from click.testing import CliRunner

    from meshdenoise.cli import cli

    res = CliRunner().invoke(cli, ["run", str(pipeline), "--serial"])
    assert res.exit_code == 0, res.output
    return out, pipeline


def _pipeline_run(tmp_path):
    """A real two-input sweep through `meshdenoise run`: inputs sharing a file name, mu and iterations swept."""
    from meshdenoise.io import save_mesh
    from meshdenoise.noise import add_normal_noise

    for folder, seed in (("a", 0), ("b", 1)):
        V, F = icosphere(2)
        (tmp_path / folder).mkdir()
        save_mesh(tmp_path / folder / "Noisy.ply", add_normal_noise((V, F), rho=0.01, seed=seed)[0], F)
    pipeline = tmp_path / "sweep <b>.yaml"
    pipeline.write_text(
        "description: 'a <b>bold</b> & \"quoted\" sweep'\n"
        "inputs: ['a/Noisy.ply', 'b/Noisy.ply']\n"
        f"output_dir: {tmp_path / 'out'}\n"
        "steps:\n"
        "  - add_noise: {rho: 0.005, relative: true, seed: 0, label: clean}\n"
        "  - taubin: {iterations: '${iterations}', lam: '${lam}'}\n"
        "  - metrics: {reference: {before: clean}, metrics: [snr, normal_error_deg]}\n"
        "  - save: {path: '{stem}_{index}_{setting}.ply'}\n"
        "sweep: {lam: [0.25, 0.5], iterations: [1, 3, 10]}\n")
    return _run(pipeline, tmp_path / "out")


def test_pipeline_report_is_one_rounded_table_with_a_chart_per_swept_parameter(tmp_path):
    out, pipeline = _pipeline_run(tmp_path)
    rows = json.loads((out / "results.json").read_text())
    assert len(rows) == 12
    page = write_report(out, pipeline=pipeline)
    text = page.read_text(encoding="utf-8")
    # one table: the CSV's rows, the JSON linked as the same rows
    assert text.count("<table>") == 1
    assert 'href="results.json"' in text and "the same rows as results.csv" in text
    # numbers to 4 significant digits, the full value as the tooltip
    full = repr(rows[0]["snr"])
    assert f'title="{full}">{rows[0]["snr"]:.4g}</td>' in text
    assert not re.search(r">-?\d+\.\d{5,}<", text)  # no long decimals left in any cell
    # inputs by their shortest distinguishing path, outputs as links inside the run folder
    assert ">a/Noisy.ply</span>" in text and ">b/Noisy.ply</span>" in text
    from urllib.parse import quote

    for row in rows:
        (output,) = row["outputs"]
        assert f'href="{quote(Path(output).name)}">{Path(output).name}</a>' in text
    # the pipeline text, escaped
    assert "a &lt;b&gt;bold&lt;/b&gt; &amp; &quot;quoted&quot; sweep" in text and "<b>bold" not in text
    assert "sweep &lt;b&gt;.yaml" in text
    # one chart per swept numeric parameter, drawn in the page
    charts = re.findall(r'<img src="data:image/png;base64,[^"]+" alt="([^"]+)"', text)
    assert charts == ["snr, normal_error_deg against lam", "snr, normal_error_deg against iterations"]
    # each output before / after / change, beside the page, with its setting
    renders = re.findall(r'<img src="(report-renders/[^"]+)" width="(\d+)" height="(\d+)"', text)
    assert [src for src, _, _ in renders] == [f"report-renders/{quote(Path(r['outputs'][0]).name)}.png" for r in rows]
    assert {(w, h) for _, w, h in renders} == {("906", "300")}  # 3 panels of 260 px, 2 gaps of 8, the bar's 110
    assert all((out / "report-renders" / f"{Path(r['outputs'][0]).name}.png").is_file() for r in rows)
    assert f"a/Noisy.ply → {Path(rows[0]['outputs'][0]).name}" in text.replace("<wbr>", "")
    assert f"(lam={rows[0]['lam']}, iterations={rows[0]['iterations']})" in text
    assert "report-renders" not in text.split("Other files")[-1]  # the report's own pictures are not listed


def test_sweep_series_against_the_rows():
    from meshdenoise.report import sweep_parameters, sweep_series

    rows = [{"input": f"/d/{d}/Noisy.ply", "lam": lam, "iterations": k, "snr": 10 * lam + k + (d == "b"),
             "auto.sobolev.mu": 2.0, "vertices": 162, "faces": 320, "seconds": 0.01, "status": "ok"}
            for d in ("a", "b") for lam in (0.5, 0.25) for k in (3, 1)]
    rows.append({"input": "/d/a/Noisy.ply", "lam": 0.75, "iterations": 1, "status": "failed", "error": "x"})
    params, metrics = sweep_parameters(rows)
    assert params == ["lam", "iterations"] and metrics == ["snr", "auto.sobolev.mu"]
    assert sweep_parameters(rows, ["iterations"]) == (["iterations"], ["snr", "auto.sobolev.mu"])
    series = sweep_series(rows, "iterations", "snr", ["lam", "iterations"])
    expected = {f"{d}/Noisy.ply, lam={lam}": [(1.0, 10 * lam + 1 + (d == "b")), (3.0, 10 * lam + 3 + (d == "b"))]
                for d in ("a", "b") for lam in (0.5, 0.25)}
    assert series == expected  # failed row left out, points sorted by x
    one = [r for r in rows if r["input"] == "/d/a/Noisy.ply" and r["lam"] == 0.5]
    assert sweep_series(one, "iterations", "snr", ["iterations"]) == {"": [(1.0, 6.0), (3.0, 8.0)]}


def test_a_swept_method_is_charted_by_name_in_row_order():
    from meshdenoise.report import sweep_parameters, sweep_series

    rows = [{"input": "/m/bunny.obj", "method": m, "snr": s, "status": "ok"}
            for m, s in (("sobolev", 49.25), ("heat", 46.86), ("open3d.filter_smooth_taubin", 42.44))]
    assert sweep_parameters(rows) == (["method"], ["snr"])
    assert sweep_series(rows, "method", "snr", ["method"]) == {
        "": [("sobolev", 49.25), ("heat", 46.86), ("open3d.filter_smooth_taubin", 42.44)]}


def test_report_fits_1280_pixels_in_chromium(tmp_path):
    """A pipeline run and a folder with a very wide table: no horizontal overflow anywhere; screenshot of each."""
    out, pipeline = _pipeline_run(tmp_path)
    page = write_report(out, pipeline=pipeline)
    assert chromium_check(page, tmp_path) == {"images": 2 + 12, "problems": [], "width": WINDOW[0]}  # charts, renders
    assert screenshot(page, tmp_path / "pipeline-report.png", tmp_path)[0] == WINDOW[0]
    wide = tmp_path / "wide"
    wide.mkdir()
    with (wide / "results.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow([f"a_rather_long_column_name_{i}" for i in range(30)])
        for r in range(5):
            w.writerow([f"{np.pi * 10 ** (r - 2) * (i + 1)!r}" for i in range(29)] + ["x" * 400])
    (wide / "notes.yaml").write_text("steps: [" + ", ".join(["sobolev"] * 200) + "]\n")
    page = write_report(wide)
    text = page.read_text()
    assert text.count("<table>") >= 3 and "part 1 of" in text  # cut into tables that fit, not scrolled
    assert chromium_check(page, tmp_path) == {"images": 0, "problems": [], "width": WINDOW[0]}
    assert screenshot(page, tmp_path / "wide-report.png", tmp_path)[0] == WINDOW[0]


def test_the_width_check_sees_an_overflow(tmp_path):
    """The measurements are real: a 2000-pixel block widens the page, a wide table in a scroll box is named."""
    page = tmp_path / "wide.html"
    page.write_text('<!DOCTYPE html><html><head><meta charset="utf-8"></head><body>'
                    '<div style="width:2000px">x</div></body></html>')
    assert chromium_check(page, tmp_path)["width"] >= 2000
    page.write_text('<!DOCTYPE html><html><head><meta charset="utf-8"></head><body>'
                    '<div style="overflow-x:auto"><table><tr><td style="white-space:nowrap">' + "x" * 600
                    + '</td></tr></table></div></body></html>')
    result = chromium_check(page, tmp_path)
    assert result["width"] == WINDOW[0] and any(p.startswith("scrolls sideways: DIV") for p in result["problems"])


def test_report_opens_in_chromium_without_errors(run_dir, tmp_path):
    page = write_report(run_dir)
    result = chromium_check(page, tmp_path)
    assert result == {"images": 2, "problems": [], "width": WINDOW[0]}


def test_embedded_report_opens_alone(run_dir, tmp_path):
    page = write_report(run_dir, embed=True, out=tmp_path / "alone.html")
    assert "data:image/png;base64," in page.read_text()
    assert chromium_check(page, tmp_path) == {"images": 2, "problems": [], "width": WINDOW[0]}


def test_embedded_scan_report_carries_its_renders(tmp_path):
    out, _ = _scan_run(tmp_path)
    page = write_report(out, embed=True, out=tmp_path / "alone.html")
    text = page.read_text()
    assert len(re.findall(r'<img src="data:image/png;base64,[^"]+" width="906" height="300"', text)) == 2
    assert not (tmp_path / "alone-renders").exists() and not (out / "report-renders").exists()
    assert chromium_check(page, tmp_path) == {"images": 2, "problems": [], "width": WINDOW[0]}


def test_chromium_check_catches_a_missing_image(run_dir, tmp_path):
    page = write_report(run_dir)
    (run_dir / "snr é.png").unlink()
    result = chromium_check(page, tmp_path)
    assert result["images"] == 2
    assert any("snr%20%C3%A9.png" in p for p in result["problems"]), result


def test_report_bad_input(tmp_path):
    with pytest.raises(ValueError, match="not a folder"):
        write_report(tmp_path / "nope")
    (tmp_path / "run").mkdir()
    with pytest.raises(ValueError, match="outside"):
        write_report(tmp_path / "run", out=tmp_path / "elsewhere.html")
    with pytest.raises(ValueError, match="pipeline .* is not a file"):
        write_report(tmp_path / "run", pipeline=tmp_path / "missing.yaml")
    (tmp_path / "run" / "bad.json").write_text("{not json")
    text = write_report(tmp_path / "run").read_text()
    assert "cannot be read as a table" in text and "{not json" in text


def test_a_csv_and_json_with_different_rows_are_both_shown(tmp_path):
    (tmp_path / "results.csv").write_text("a,b\n1,2\n")
    (tmp_path / "results.json").write_text(json.dumps([{"a": 1, "b": 2}, {"a": 3, "b": 4}]))
    text = write_report(tmp_path).read_text()
    assert text.count("<table>") == 2


def test_report_cli(run_dir, tmp_path):
    from click.testing import CliRunner

    from meshdenoise.cli import cli

    res = CliRunner().invoke(cli, ["report", str(run_dir)])
    assert res.exit_code == 0, res.output
    assert (run_dir / "report.html").is_file() and "wrote" in res.output
    pipeline = tmp_path / "p.yaml"
    pipeline.write_text("steps: [sobolev]  # <i>\n")
    res = CliRunner().invoke(cli, ["report", str(run_dir), "--pipeline", str(pipeline)])
    assert res.exit_code == 0, res.output
    assert "steps: [sobolev]  # &lt;i&gt;" in (run_dir / "report.html").read_text()


# --- a scan clean-up: no sweep, each output before / after / change -------------------------------------------
ODD = "scan <b>&amp; 'q' $x$.ply"  # a file name that is markup, an entity, quotes and mathtext
LONG = "a_rather_long_scan_file_name_straight_from_the_scanner_software_0001.ply"


def _scan_run(tmp_path):
    """A clean-up of two scans through `meshdenoise run` (no sweep): one with an odd name, one with a long one."""
    from meshdenoise.io import save_mesh
    from meshdenoise.noise import add_normal_noise
    from meshdenoise.shapes import torus

    for name, (V, F), seed in ((ODD, icosphere(3), 0), (LONG, torus(40, 20), 1)):
        save_mesh(tmp_path / name, add_normal_noise((V, F), rho=0.01, seed=seed)[0], F)
    pipeline = tmp_path / "cleanup.yaml"
    pipeline.write_text(
        "description: 'clean two <i>scans</i>'\n"
        f"inputs: {json.dumps([str(tmp_path / ODD), str(tmp_path / LONG)])}\n"
        f"output_dir: {tmp_path / 'out'}\n"
        "steps:\n"
        "  - taubin: {iterations: 10}\n"
        "  - save: {path: '{stem}_clean.ply'}\n")
    return _run(pipeline, tmp_path / "out")


def test_scan_cleanup_report_shows_each_output_and_nothing_that_was_not_run(tmp_path):
    out, pipeline = _scan_run(tmp_path)
    for given in (None, pipeline):
        text = write_report(out, pipeline=given).read_text(encoding="utf-8")
        assert "Sweep" not in text and "against" not in text  # no sweep: no chart
        assert "<h2>Outputs: before / after / change</h2>" in text
        srcs = re.findall(r'<img src="([^"]+)" width="906" height="300"', text)
        stems = [Path(ODD).stem, Path(LONG).stem]
        from urllib.parse import quote

        assert srcs == [f"report-renders/{quote(s + '_clean.ply')}.png" for s in stems]
        # user text escaped everywhere: the file name, in the caption and the table
        assert "<b>" not in text and "scan &lt;b&gt;&amp;amp; &#x27;q&#x27; $x$.ply → " in text.replace("<wbr>", "")
        assert "<i>scans</i>" not in text
    assert "clean two &lt;i&gt;scans&lt;/i&gt;" in text  # the description under the title
    assert sorted(p.name for p in (out / "report-renders").iterdir()) == sorted(f"{s}_clean.ply.png" for s in stems)


def test_scan_report_pictures_load_and_show_in_a_screenshot(tmp_path):
    """Headless Chromium: every picture loads, nothing scrolls sideways, and a screenshot of the whole page
    shows each before / after / change picture pixel for pixel where the page puts it."""
    out, pipeline = _scan_run(tmp_path)
    page = write_report(out, pipeline=pipeline)
    result = chromium_check(page, tmp_path, boxes=True)
    assert result["images"] == 2 and result["problems"] == [] and result["width"] == WINDOW[0]
    shot = tmp_path / "scan-report.png"
    assert screenshot(page, shot, tmp_path, height=result["height"]) == (WINDOW[0], result["height"])
    from urllib.parse import unquote

    import matplotlib.image

    img = (matplotlib.image.imread(shot)[:, :, :3] * 255).round()
    for box in result["boxes"]:
        picture = (matplotlib.image.imread(out / unquote(box["src"]))[:, :, :3] * 255).round()
        assert box["natural"] == [picture.shape[1], picture.shape[0]] == [box["w"], box["h"]]  # shown at its size
        x, y = round(box["x"]), round(box["y"])
        seen = img[y:y + box["h"], x:x + box["w"]]
        assert seen.shape == picture.shape
        assert np.abs(seen - picture).mean() < 2, box["src"]
        assert (picture < 200).any(axis=2).mean() > 0.1  # and the picture is not blank


def test_report_renders_are_kept_while_newer_than_their_meshes(tmp_path, monkeypatch):
    import os

    import meshdenoise.render as render

    out, _ = _scan_run(tmp_path)
    write_report(out)
    drawn = []
    draw = render.render_comparison
    monkeypatch.setattr(render, "render_comparison", lambda meshes, png, **k: (drawn.append(Path(png).name),
                                                                              draw(meshes, png, **k))[1])
    write_report(out)
    assert drawn == []  # both pictures newer than their meshes: kept
    mesh = out / f"{Path(LONG).stem}_clean.ply"
    later = (out / "report-renders" / f"{mesh.name}.png").stat().st_mtime + 10
    os.utime(mesh, (later, later))  # the output written again after its picture
    (out / "report-renders" / "gone.ply.png").write_bytes(b"x")  # a picture of an output no longer in the results
    write_report(out)
    assert drawn == [f"{mesh.name}.png"]
    assert not (out / "report-renders" / "gone.ply.png").exists()
    from click.testing import CliRunner

    from meshdenoise.cli import cli

    res = CliRunner().invoke(cli, ["report", str(out), "--no-renders"])
    assert res.exit_code == 0, res.output
    assert "Outputs" not in (out / "report.html").read_text() and len(drawn) == 1


def test_a_mesh_that_cannot_be_drawn_is_named_and_the_rest_drawn(tmp_path):
    out, _ = _scan_run(tmp_path)
    (out / f"{Path(LONG).stem}_clean.ply").write_text("not a mesh")
    text = write_report(out).read_text()
    assert len(re.findall(r'width="906" height="300"', text)) == 1
    assert "_clean.ply: not drawn (" in text.replace("<wbr>", "")


def test_without_the_pipeline_the_columns_steps_add_are_not_a_sweep():
    """The `denoise` step's columns (denoise.method, ...) vary over inputs but were not swept."""
    from meshdenoise.report import sweep_parameters

    rows = [{"input": f"/s/{n}.ply", "status": "ok", "denoise.method": m, "denoise.noise": z, "snr": s,
             "auto.sobolev.mu": mu, "vertices": 10, "faces": 16, "seconds": 1.0}
            for n, m, z, s, mu in (("a", "sobolev", 0.01, 40.0, 2.0), ("b", "two_stage", 0.02, 38.0, 3.0))]
    assert sweep_parameters(rows)[0] == []
    assert sweep_parameters([{**r, "mu": r["auto.sobolev.mu"]} for r in rows])[0] == ["mu"]  # a variable is


def test_a_pipeline_without_sweep_draws_no_chart(tmp_path):
    rows = [{"input": f"/s/{n}.ply", "status": "ok", "mu": mu, "snr": s}
            for n, mu, s in (("a", 1.0, 40.0), ("b", 2.0, 38.0))]
    (tmp_path / "results.json").write_text(json.dumps(rows))
    (tmp_path / "p.yaml").write_text("steps: [sobolev]\n")  # no sweep: mu is a per-input value, not swept
    assert "Sweep" not in write_report(tmp_path, renders=False).read_text()
    (tmp_path / "p.yaml").write_text("steps: [sobolev]\nsweep: {mu: [1.0, 2.0]}\n")
    assert "<h3>Sweep</h3>" in write_report(tmp_path, renders=False).read_text()


def test_chart_axis_labels_are_mathtext_drawn_and_names_are_plain_text(tmp_path):
    """A log axis labels its ticks 10^-2 through mathtext; the source `$\\mathdefault{...}$` is never drawn
    as text, and a `$` in a name stays a dollar sign. Read from an SVG of the chart with its text as text."""
    import matplotlib

    from meshdenoise.report.charts import _chart_figure

    rows = [{"input": f"/s/{name}", "status": "ok", "mu": mu, "snr": 30 + mu}
            for name in ("a$b$.ply", "c.ply") for mu in (0.001, 0.01, 0.1, 1.0)]
    fig = _chart_figure(rows, "mu", ["snr"], ["mu"])
    buf = io.StringIO()
    with matplotlib.rc_context({"svg.fonttype": "none"}):
        fig.savefig(buf, format="svg")
    svg = re.sub(r"<!--.*?-->", "", buf.getvalue(), flags=re.S)  # the comments quote each text's source
    assert "mathdefault" not in svg and "\\$" not in svg
    assert "a$b$.ply" in svg  # the legend names the input as it is
    ticks = [t.get_text() for t in fig.axes[0].get_xticklabels()]
    assert any("10^{-2}" in t for t in ticks)  # the axis is logarithmic, labelled by mathtext
