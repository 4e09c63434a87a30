"""The docs site builds with ``mkdocs build --strict``, its tutorials executed, offline.

One build covers both: the tutorial notebooks (jupytext scripts in docs/tutorials/) are
executed by mkdocs-jupyter while the site is built, at the small sizes their
``ESPIN_TUTORIAL_QUICK`` switch selects; a failing cell fails the build. Any network request
during the build would go to a closed port and fail it (no web fonts, no remote inventories).
"""

from __future__ import annotations

import html
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow  # builds the whole site: a minute or more

ROOT = Path(__file__).resolve().parents[2]
DEAD_PROXY = "http://127.0.0.1:9"
"""A port nothing listens on: every HTTP(S) request through it fails."""


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("site")
    # As the README's command builds it: no MPLBACKEND, so the notebooks draw their figures
    # inline (MPLBACKEND=Agg would leave out every plt.show() figure).
    env = {k: v for k, v in os.environ.items() if k != "MPLBACKEND"} | {
                        "ESPIN_TUTORIAL_QUICK": "1", "NO_MKDOCS_2_WARNING": "1",
                        "HTTP_PROXY": DEAD_PROXY, "HTTPS_PROXY": DEAD_PROXY, "http_proxy": DEAD_PROXY,
                        "https_proxy": DEAD_PROXY, "NO_PROXY": "", "no_proxy": ""}
    run = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--config-file",
                          str(ROOT / "mkdocs.yml"), "--site-dir", str(out)],
                         cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, f"mkdocs build --strict failed:\n{run.stdout[-4000:]}\n{run.stderr[-8000:]}"
    return out


TEX = re.compile(r"\\\(|\\\)|\\\[|\\\]|\$\$|(?<![\w$])\$[^\s$][^$]*?(?<!\s)\$")
"""A TeX delimiter: ``\\( \\) \\[ \\] $$`` or a ``$...$`` span."""


def raw_tex(page: str) -> list[str]:
    """The TeX delimiters left in the text a reader sees on a page (outside code, scripts,
    styles, typeset MathML and the notebooks' hidden copy of each code cell): math that was
    not converted."""
    text = re.sub(r'<div class="clipboard-copy-txt".*?</div>', " ", page, flags=re.S)
    text = re.sub(r"<(script|style|pre|code|math)\b.*?</\1>", " ", text, flags=re.S | re.I)
    text = html.unescape(re.sub(r"<[^>]*>", " ", text))
    return TEX.findall(text)


def _page(site: Path, name: str) -> str:
    return (site / name / "index.html").read_text(encoding="utf-8")


def test_every_page_of_the_nav_is_built(site):
    nav = (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
    pages = (re.findall(r":\s+(\S+\.(?:md|py))\s*$", nav, flags=re.M)
             + re.findall(r"^\s+- (\S+\.md)\s*$", nav, flags=re.M))
    assert len(pages) >= 25
    for page in pages:
        stem = page.rsplit(".", 1)[0]
        built = site / "index.html" if stem == "index" else site / stem.removesuffix("/index") / "index.html"
        assert built.exists(), f"{page} was not built"


def test_nav_names_each_page_once():
    # A reader tells the pages apart by their names in the nav: no name twice (a guide and its
    # API page, a tutorial and its guide).
    nav = (ROOT / "mkdocs.yml").read_text(encoding="utf-8").split("\nnav:", 1)[1].split("\n\n", 1)[0]
    names = re.findall(r"^\s+- ([^:\n]+):", nav, flags=re.M)
    assert len(names) >= 30 and len(names) == len(set(names)), sorted(n for n in names if names.count(n) > 1)


def test_api_reference_is_rendered_from_the_docstrings(site):
    mechanics = _page(site, "api/mechanics")
    # The signature and a sentence of the numpy docstring of espin.simulate and its parameters.
    assert "simulate" in mechanics and "Pull on a virtual mat and record its stress-strain response" in mechanics
    assert "overwrite" in mechanics and "on_step" in mechanics
    datasets = _page(site, "api/datasets")
    assert "SEM-like image" in datasets and "calibrated_config" in datasets


def test_tutorials_are_executed_with_their_outputs(site):
    # Jupyter shows espin's objects by their _repr_html_ tables; matplotlib figures as PNG.
    first = _page(site, "tutorials/fifteen_minutes")
    for caption in ("RVE", "SimulationResult", "ResultsFile"):
        assert f"<caption>{caption}</caption>" in first
    # espin.simulate's notebook progress bar, in its final state.
    assert re.search(r'<progress[^>]*value="15"', first) and "step 15/15" in first
    assert first.count("data:image/png;base64") >= 3  # the 3-D mat, the curve, curve.png
    sem = _page(site, "tutorials/sem_to_curve")
    assert "<caption>SEMMeasurement of" in sem and "<caption>GeometryCalibration of" in sem
    fit = _page(site, "tutorials/fit_curves")
    assert "<caption>FitResult" in fit and "chord modulus" in fit and "<caption>DesignResult" in fit
    # The fit's own status line, and no progress bar of each simulation it ran; the design's
    # one bar of its budget's tests (none per batch or simulation).
    assert re.search(r"evaluation \d+  SSE", fit)
    assert fit.count("<progress") == 1 and re.search(r'<progress[^>]*max="10"', fit)


def test_home_page_links_the_guides(site):
    home = (site / "index.html").read_text(encoding="utf-8")
    for target in ("getting_started/", "tutorials/fifteen_minutes/", "api/", "model/"):
        assert f'href="{target}' in home or f'href="./{target}' in home, target


def test_the_raw_tex_check_sees_a_formula_left_raw():
    assert raw_tex(r"<p>Let \(x\) be the strain.</p>") == ["\\(", "\\)"]
    assert raw_tex(r"<div>\[E = 1\]</div>") and raw_tex(r"<p>the volume fraction $\eta$</p>")
    assert raw_tex(r"<p>$$\sigma$$</p>")
    for typeset in (r"<p><code>\(x\)</code> and <math><mi>x</mi></math></p>",
                    r"<pre>echo $HOME $PATH</pre>", "<p>costs 5 $ or 6 $</p>"):
        assert raw_tex(typeset) == [], typeset


def test_math_is_typeset_as_mathml_on_every_page(site):
    # The model page's formulas and the tutorials' Markdown math, as MathML the browser
    # typesets with no script and no network; no TeX delimiter left in any page's text.
    model = _page(site, "model")
    assert model.count("<math ") >= 100 and 'class="arithmatex"' not in model
    assert "<math " in _page(site, "tutorials/fit_curves")
    left = {str(p.relative_to(site)): raw_tex(p.read_text(encoding="utf-8")) for p in site.rglob("*.html")}
    assert {page: found for page, found in left.items() if found} == {}
    pages = "".join(p.read_text(encoding="utf-8") for p in site.rglob("*.html"))
    assert not re.search(r'<script[^>]*src=""', pages)
    # A TeX command the converter does not know would be shown as its name: none is.
    assert not re.findall(r"<m[a-z]+[^>]*>\\[A-Za-z]+", pages)
