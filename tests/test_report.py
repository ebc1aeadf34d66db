"""The run report: content, escaping, and a check in headless Chromium that it loads cleanly."""

from __future__ import annotations

import csv
import json
import re
import shutil
import subprocess

import numpy as np
import pytest

from meshdenoise.render import render_comparison
from meshdenoise.report import write_report
from meshdenoise.shapes import icosphere

# Put first in <head>: records console errors, script errors and failed resource loads, then after
# load every <img> that did not decode, into <pre id="page-check"> for --dump-dom to show.
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
    imgs.forEach(function (img) { if (!img.complete || img.naturalWidth === 0) problems.push("image not loaded: " + img.src); });
    var pre = document.createElement("pre"); pre.id = "page-check";
    pre.textContent = JSON.stringify({images: imgs.length, problems: problems});
    document.body.appendChild(pre);
  });
})();
</script>"""


def chromium_check(page, tmp_path) -> dict:
    """Open a copy of ``page`` (same folder, so relative links hold) with the checker in headless Chromium."""
    exe = shutil.which("chromium") or shutil.which("chromium-browser")
    if exe is None:
        pytest.fail("headless Chromium is needed to check the report: install the Debian package 'chromium' "
                    "(scripts/install-system-deps.sh does, and `make test` runs it)")
    probe = page.with_name(".check-" + page.name)
    probe.write_text(page.read_text(encoding="utf-8").replace("<head>", "<head>" + CHECKER, 1), encoding="utf-8")
    cmd = [exe, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
           "--disable-background-networking", "--disable-component-update", "--disable-sync",
           f"--user-data-dir={tmp_path / 'chromium-profile'}", "--virtual-time-budget=10000",
           "--dump-dom", probe.resolve().as_uri()]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    probe.unlink()
    found = re.search(r'<pre id="page-check">(.*?)</pre>', proc.stdout, re.S)
    assert found, f"Chromium gave no page check (exit {proc.returncode}): {proc.stderr[-2000:]}"
    import html

    return json.loads(html.unescape(found.group(1)))


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
    assert page == run_dir / "report.html"
    assert "<script>alert(1)</script>" not in text and "&lt;script&gt;alert(1)&lt;/script&gt;" in text
    assert "a&amp;b &quot;q&quot;" in text
    assert '<td class="num">31.25</td>' in text and "<td>sobolev</td>" in text
    assert "<th>snr.db</th>" in text and '<td class="num">20.5</td>' in text  # nested JSON flattened
    assert "<td>Vaillant-Tenzer 2022</td>" in text
    assert 'src="renders/before%20after%20%231.png"' in text and 'src="snr%20%C3%A9.png"' in text
    assert 'href="sobolev.ply"' in text
    assert "<script" not in text.replace("&lt;script", "")  # the page itself runs no script


def test_report_opens_in_chromium_without_errors(run_dir, tmp_path):
    page = write_report(run_dir)
    result = chromium_check(page, tmp_path)
    assert result == {"images": 2, "problems": []}


def test_embedded_report_opens_alone(run_dir, tmp_path):
    page = write_report(run_dir, embed=True, out=tmp_path / "alone.html")
    assert "data:image/png;base64," in page.read_text()
    assert chromium_check(page, tmp_path) == {"images": 2, "problems": []}


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
    (tmp_path / "run" / "bad.json").write_text("{not json")
    text = write_report(tmp_path / "run").read_text()
    assert "cannot be read as a table" in text and "{not json" in text


def test_report_cli(run_dir):
    from click.testing import CliRunner

    from meshdenoise.cli import cli

    res = CliRunner().invoke(cli, ["report", str(run_dir)])
    assert res.exit_code == 0, res.output
    assert (run_dir / "report.html").is_file() and "wrote" in res.output
