"""The site in a real browser: Debian's chromium, headless, driven by chromium-driver through
Selenium, over a site built from the committed results (and clips made here). Skips with one
line where the browser or its driver is absent; .ci/run installs both.

ZOO_SITE_SCREENSHOTS=folder keeps the screenshots there (docs/site/ holds the README's)."""

from __future__ import annotations

import json
import os
import shutil
import time
from pathlib import Path

import numpy as np
import pytest

from zoo.paths import REPO_ROOT
from zoo.site import build_site

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
DRIVER = shutil.which("chromedriver")
webdriver = pytest.importorskip("selenium.webdriver", reason="selenium is not installed")
pytestmark = pytest.mark.skipif(
    not (CHROMIUM and DRIVER),
    reason="no chromium and chromium-driver here (apt-get install -y chromium chromium-driver)",
)
RESULTS = REPO_ROOT / "results"


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    from zoo.report.clips import Clips

    tmp = tmp_path_factory.mktemp("site")
    results = tmp / "results"
    for bench in ("cmu", "cmu50", "cmu_anny_oi_low"):
        shutil.copytree(RESULTS / bench, results / bench, ignore=shutil.ignore_patterns("*.npz"))
    # one empty cell, where a sort must put it last either way
    table = results / "cmu" / "all" / "summary.json"
    summary = json.loads(table.read_text())
    summary["views"][0]["models"][0]["values"][3] = None
    table.write_text(json.dumps(summary))
    clips = RESULTS / "cmu_anny_oi_low" / "clips.npz"
    if clips.is_file():
        shutil.copy(clips, results / "cmu_anny_oi_low" / "clips.npz")
    else:  # a tetrahedron walking, where the committed clips are not there
        t = np.linspace(0, 400, 35)[None, :, None, None]
        body = np.array([[0, 0, 0], [300, 0, 0], [0, 300, 0], [0, 0, 1700.0]])[None, None]
        truth = np.repeat(body + np.stack([t[..., 0], 0 * t[..., 0], 0 * t[..., 0]], -1), 2, 0)
        Clips(
            "cmu_anny_oi_low",
            25.0,
            10,
            np.array([1, 2]),
            ["a", "b"],
            np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]]),
            np.arange(4),
            truth,
            {"spectrhums": truth[:, 10:] + 20.0},
        ).write(results / "cmu_anny_oi_low" / "clips.npz")
    # a row from imported weights whose licence keeps them out of the repository (TFAN's
    # authors' record), as one's own tables may hold; the committed ones hold none
    authors = json.loads((REPO_ROOT / "weights" / "cmu50" / "tfan@authors.json").read_text())
    row = results / "cmu50" / "all" / "pgbig" / "protocol.json"
    record = json.loads(row.read_text())
    record["provenance"]["imported"] = authors["imported"]
    row.write_text(json.dumps(record))
    build = build_site(tmp / "site", results)
    assert build.warnings == []
    return build.out


@pytest.fixture(scope="module")
def pristine_site(tmp_path_factory) -> Path:
    """The site of the committed results as they are: what the README's pictures show."""
    tmp = tmp_path_factory.mktemp("pristine")
    for bench in ("cmu", "cmu50", "cmu_anny_oi_low"):
        shutil.copytree(RESULTS / bench, tmp / "results" / bench)
    return build_site(tmp / "site", tmp / "results").out


@pytest.fixture(scope="module")
def browser():
    from selenium.webdriver.chrome.options import Options
    from selenium.webdriver.chrome.service import Service

    options = Options()
    options.binary_location = CHROMIUM
    for flag in ("--headless=new", "--no-sandbox", "--disable-gpu", "--window-size=1280,1400"):
        options.add_argument(flag)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(service=Service(DRIVER), options=options)
    yield driver
    driver.quit()


def _load(browser, address: str) -> None:
    """``address`` loaded and its scripts run: chromedriver can answer a navigation while the
    page is still loading (seen with an address that holds a fragment), before its scripts ran.
    The document left behind is marked, so that its own "complete" is not taken for the new
    one's."""
    from selenium.common.exceptions import JavascriptException
    from selenium.webdriver.support.ui import WebDriverWait

    browser.execute_script("window.zooLeft = true")
    browser.get(address)
    WebDriverWait(
        browser, 30, poll_frequency=0.02, ignored_exceptions=(JavascriptException,)
    ).until(
        lambda b: b.execute_script("return !window.zooLeft && document.readyState == 'complete'")
    )


def _open(browser, page: Path, fragment: str = ""):
    _load(browser, page.as_uri() + fragment)
    browser.get_log("browser")  # drop what an earlier page logged


def _shot(browser, name: str, tmp_path: Path) -> Path:
    folder = Path(os.environ.get("ZOO_SITE_SCREENSHOTS") or tmp_path)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / name
    browser.save_screenshot(str(path))
    return path


def _not_blank(path: Path) -> None:
    from matplotlib.image import imread

    pixels = imread(path)[..., :3].reshape(-1, 3)
    rgb = (pixels * 255).round().astype(np.uint32) @ np.array([1 << 16, 1 << 8, 1], np.uint32)
    colours = len(np.unique(rgb))  # one number per colour: unique rows of 3 sort far slower
    assert colours > 50, f"{path}: {colours} colours, a blank page"
    assert pixels.std() > 0.05


def test_every_page_loads_without_console_errors_or_outside_requests(browser, site):
    pages = sorted(site.glob("*.html"))
    assert len(pages) >= 10
    for page in pages:
        _load(browser, page.as_uri())
        errors = [e for e in browser.get_log("browser") if e["level"] in ("SEVERE", "ERROR")]
        assert errors == [], f"{page.name}: {errors}"
        requested = browser.execute_script(
            "return performance.getEntriesByType('resource').map(e => e.name)"
        )
        outside = [u for u in requested if not u.startswith(site.as_uri() + "/")]
        assert outside == [], f"{page.name} requested {outside}"
        assert browser.execute_script("return document.body.innerText.length") > 200


# In the page, what Selenium's is_displayed and text say of an element: a hidden one, no text.
_SHOWN = (
    "const shown = e => e.checkVisibility({opacityProperty: true, visibilityProperty: true});"
    "const text = e => (shown(e) ? e.innerText : '');"
)


def _each(browser, selector: str, expression: str) -> list:
    """``expression`` (JavaScript, of the element ``e``; ``shown(e)`` and ``text(e)`` as
    Selenium's is_displayed and text) for every element ``selector`` matches, in one call:
    Selenium's get_attribute, is_displayed and text are a round trip per element, each running a
    large script in the page."""
    return browser.execute_script(
        f"{_SHOWN} return [...document.querySelectorAll(arguments[0])].map(e => {expression})",
        selector,
    )


def _models(browser) -> list[str]:
    """The board's rows, as shown."""
    return _each(browser, "#board tbody tr[data-model]", "e.dataset.model")


def _column(browser, horizon: int) -> list[float | None]:
    values = _each(
        browser, f"#board tbody tr[data-model] td[data-horizon='{horizon}']", "e.dataset.value"
    )
    return [float(v) if v else None for v in values]


def test_sorting_a_column_orders_its_rows(browser, site):
    _open(browser, site / "table-cmu-all.html")
    header = browser.find_element("css selector", "#board th[data-key='3']")
    horizon = int(header.text.split()[0])
    header.click()
    values = _column(browser, horizon)
    numbers = [v for v in values if v is not None]
    assert values == sorted(numbers) + [None] and len(numbers) >= 4  # the empty cell last
    browser.find_element("css selector", "#board th[data-key='3']").click()
    assert _column(browser, horizon) == sorted(numbers, reverse=True) + [None]
    browser.find_element("css selector", "#board th[data-key='model']").click()
    names = _models(browser)
    assert names == sorted(names)


def test_switching_the_view_shows_the_stored_values(browser, site):
    import json

    from selenium.webdriver.support.ui import Select

    summary = json.loads(
        (RESULTS / "cmu_anny_oi_low" / "stride5_strict" / "summary.json").read_text()
    )
    _open(browser, site / "table-cmu_anny_oi_low-stride5_strict.html")
    Select(browser.find_element("id", "metric")).select_by_value("melv")
    Select(browser.find_element("id", "averaging")).select_by_value("cumulative")
    view = next(
        v for v in summary["views"] if v["metric"] == "melv" and v["averaging"] == "cumulative"
    )
    h = view["horizons_ms"][2]
    shown = dict(
        _each(
            browser,
            "#board tbody tr[data-model]",
            f"[e.dataset.model, +e.querySelector(\"td[data-horizon='{h}']\").dataset.value]",
        )
    )
    stored = {m["model"]: m["values"][2] for m in view["models"] if "@" not in m["model"]}
    assert shown == pytest.approx(stored) and len(shown) >= 3
    # @last rows appear only when asked for
    assert not any("@" in m for m in shown)
    browser.find_element("id", "show-last").click()
    assert any("@last" in m for m in _models(browser))
    # per action: the stored per-action value
    Select(browser.find_element("id", "action")).select_by_index(1)
    action = Select(browser.find_element("id", "action")).first_selected_option.text
    model = view["models"][0]
    cell = browser.find_element(
        "css selector", f"#board tr[data-model='{model['model']}'] td[data-horizon='{h}']"
    )
    assert float(cell.get_attribute("data-value")) == pytest.approx(model["per_action"][action][2])


def test_switching_the_metric_keeps_the_averaging_where_it_can(browser, site):
    from selenium.webdriver.support.ui import Select

    _open(browser, site / "table-cmu_anny_oi_low-stride5_strict.html")
    assert Select(browser.find_element("id", "averaging")).first_selected_option.text == "frame"
    Select(browser.find_element("id", "metric")).select_by_value("mpjpe")
    chosen = [
        Select(browser.find_element("id", name)).first_selected_option.text
        for name in ("metric", "averaging", "joints")
    ]
    assert chosen == ["mpjpe", "frame", "regressor31"]
    note = browser.find_element("id", "protocol-note").text
    assert note.startswith("MPJPE (mm), averaging frame")


def test_the_mesh_viewer_advances_frames(browser, site):
    _open(browser, site / "meshes-cmu_anny_oi_low.html")
    viewer = browser.find_element("id", "viewer")
    first = viewer.get_attribute("data-frame")
    assert first is not None
    browser.find_element("id", "play").click()
    deadline = time.time() + 20
    while viewer.get_attribute("data-frame") == first and time.time() < deadline:
        time.sleep(0.2)
    assert viewer.get_attribute("data-frame") != first
    browser.find_element("id", "play").click()  # pause
    browser.execute_script(
        "var s = document.getElementById('frame'); s.value = s.max;"
        "s.dispatchEvent(new Event('input'));"
    )
    last = int(browser.find_element("id", "frame").get_attribute("max"))
    assert int(viewer.get_attribute("data-frame")) == last
    time.sleep(1.0)  # paused: no frame drawn since, whatever a frame takes to draw here
    assert int(viewer.get_attribute("data-frame")) == last
    captions = [c.text for c in browser.find_elements("css selector", "#viewer figcaption")]
    assert any("mean vertex error" in c for c in captions)


def test_screenshots_are_not_blank(browser, pristine_site, tmp_path):
    """The README's pictures (ZOO_SITE_SCREENSHOTS=docs/site keeps them), taken from the
    committed results; beside the table's, the numbers it shows (test_readme.py holds them to
    the committed tables, so a stale picture fails)."""
    site = pristine_site
    _open(browser, site / "index.html")
    _not_blank(_shot(browser, "index.png", tmp_path))
    _open(browser, site / "table-cmu-all.html")
    picture = _shot(browser, "table-cmu.png", tmp_path)
    _not_blank(picture)
    shown = browser.execute_script(
        "return [...document.querySelectorAll('#board tbody tr[data-model]')].map(r => "
        "[r.getAttribute('data-model'), [...r.querySelectorAll('td[data-horizon]')]"
        ".filter(c => c.offsetParent !== null).map(c => [+c.getAttribute('data-horizon'), "
        "c.getAttribute('data-value') === '' ? null : +c.getAttribute('data-value')])])"
    )
    pictured = {"table": "results/cmu/all", "rows": {m: dict(cells) for m, cells in shown}}
    picture.with_suffix(".json").write_text(json.dumps(pictured, indent=1) + "\n")
    _open(browser, site / "table-cmu50-all.html")  # each row's history, read and padded
    _not_blank(_shot(browser, "table-cmu50.png", tmp_path))
    _open(browser, site / "meshes-cmu_anny_oi_low.html")
    browser.execute_script(
        "var s = document.getElementById('frame'); s.value = s.max;"
        "s.dispatchEvent(new Event('input'));"
    )
    _not_blank(_shot(browser, "meshes-cmu_anny_oi_low.png", tmp_path))


@pytest.mark.parametrize("width, height", [(1366, 768), (1920, 1080)])
def test_a_table_fits_the_screen_on_load_with_its_rows_ranked(browser, site, width, height):
    """The last horizon and the model column in view on load at a laptop's and a desktop's
    size; rows ranked at the longest horizon, ranks in order."""
    browser.set_window_size(width, height)
    try:
        pages = (
            "table-cmu-all.html",
            "table-cmu50-all.html",
            "table-cmu_anny_oi_low-stride5_strict.html",
        )
        for page in pages:
            _open(browser, site / page)
            inner = browser.execute_script("return document.documentElement.clientWidth")
            described = "[text(e), e.className, e.getBoundingClientRect().toJSON()]"
            headers = "#board thead th.sortable.num"
            horizons = [h for h in _each(browser, headers, f"shown(e) && {described}") if h]
            (model,) = _each(browser, "#board th.model", described)
            for label, _, rect in (horizons[-1], model):
                assert 0 <= rect["left"] and rect["right"] <= inner, (page, label, rect, inner)
            assert horizons[-1][1].split().count("asc") == 1
            ranks = [int(t) for t in _each(browser, "#board tbody td.rank", "text(e)") if t]
            assert ranks and ranks == sorted(ranks) and ranks[0] == 1
    finally:
        browser.set_window_size(1280, 1400)


def test_the_50_frame_table_shows_the_history_each_row_read(browser, site):
    """cmu50: every hosted CMU model has a row, each tagged with the frames it read; the
    10-frame table, where every row read all it was given, has no tag."""
    browser.set_window_size(1366, 768)
    try:
        _open(browser, site / "table-cmu50-all.html")
        tags = dict(
            _each(
                browser,
                "#board tbody tr[data-model]",
                "[e.getAttribute('data-model'), "
                "(e.querySelector('.tag.history') || {}).textContent]",
            )
        )
        assert {"ltd", "pgbig", "spgsn", "spgsn_1body", "mlp", "repeat_last"} <= set(tags)
        assert (
            tags["pgbig"] == "history: last 10 of 50" and tags["repeat_last"] == "history: all 50"
        )
        _open(browser, site / "table-cmu-all.html")
        assert not browser.find_elements("css selector", "#board .tag.history")
    finally:
        browser.set_window_size(1280, 1400)


def test_a_view_in_the_fragment_reopens(browser, site):
    page = site / "table-cmu-all.html"
    _open(browser, page)
    browser.find_element("id", "show-last").click()
    browser.find_element("css selector", "#board th[data-key='3']").click()
    browser.find_element("css selector", "#board th[data-key='3']").click()  # descending
    fragment = browser.execute_script("return location.hash")
    assert "sort=3" in fragment and "desc=1" in fragment and "last=1" in fragment
    shown = _models(browser)
    browser.get("about:blank")  # a new document: a jump within one applies it on hashchange, later
    _open(browser, page, fragment)
    again = _models(browser)
    assert again == shown and any("@last" in m for m in again)
    assert browser.find_element("id", "show-last").is_selected()


def test_the_csv_download_holds_the_stored_rows(browser, site):
    import csv
    import io
    import urllib.parse

    summary = json.loads((site.parent / "results" / "cmu" / "all" / "summary.json").read_text())
    _open(browser, site / "table-cmu-all.html")
    browser.find_element("id", "show-last").click()
    href = browser.find_element("id", "download").get_attribute("href")
    assert href.startswith("data:text/csv")
    rows = list(csv.DictReader(io.StringIO(urllib.parse.unquote(href.split(",", 1)[1]))))
    view = summary["views"][0]
    stored = {m["model"]: m["values"] for m in view["models"]}
    assert {r["model"] for r in rows} == set(stored)
    for r in rows:
        assert r["protocol_id"] == summary["protocol_id"]
        for h, value in zip(view["horizons_ms"], stored[r["model"]]):
            got = r[f"{h}_ms"]
            assert (got == "" and value is None) or float(got) == pytest.approx(value, abs=0)


def test_hiding_a_model_from_the_legend_removes_its_curve_and_rescales(browser, site):
    _open(browser, site / "table-cmu-all.html")
    selector = "#curves g.series[data-series='repeat_last']"
    assert browser.find_elements("css selector", selector)
    top = browser.execute_script(
        "return Math.max(...[...document.querySelectorAll('#curves text.tick[text-anchor=end]')]"
        ".map(t => +t.textContent))"
    )
    browser.find_element(
        "css selector", "#curves g.legend-entry[data-series='repeat_last']"
    ).click()
    assert not browser.find_elements("css selector", selector)
    assert browser.find_elements("css selector", "#curves g.series[data-series='pgbig']")
    rescaled = browser.execute_script(
        "return Math.max(...[...document.querySelectorAll('#curves text.tick[text-anchor=end]')]"
        ".map(t => +t.textContent))"
    )
    assert rescaled < top  # repeat-last no longer sets the y range
    browser.find_element(
        "css selector", "#curves g.legend-entry[data-series='repeat_last']"
    ).click()
    assert browser.find_elements("css selector", selector)


def test_a_short_trained_row_links_its_note_to_the_card(browser, site):
    _open(browser, site / "table-cmu_anny_oi_low-stride5_strict.html")
    tag = browser.find_element("css selector", "#board tr[data-model='spectrhums'] .short")
    assert tag.text == "short training" and "its run" in tag.get_attribute("title")
    assert tag.get_attribute("href").endswith("model-spectrhums.html")
    _open(browser, site / "table-cmu-all.html")  # trained to their recipes
    for model in ("spgsn", "pgbig"):
        assert not browser.find_elements("css selector", f"#board tr[data-model='{model}'] .short")


@pytest.mark.slow  # every frame of every window at two turns: .ci/run runs it after the rest
def test_every_mesh_frame_fits_its_canvas_and_repeat_last_has_a_panel(browser, site):
    """Every frame of every window of the clips, at the default turn and turned a quarter:
    no pixel but the background on any canvas's edge; repeat_last drawn beside the models."""
    from selenium.webdriver.support.ui import Select

    _open(browser, site / "meshes-cmu_anny_oi_low.html")
    edges = """
        return [...document.querySelectorAll('#viewer canvas')].map(c => {
          const g = c.getContext('2d'), w = c.width, h = c.height;
          const strips = [g.getImageData(0, 0, w, 1), g.getImageData(0, h - 1, w, 1),
                          g.getImageData(0, 0, 1, h), g.getImageData(w - 1, 0, 1, h)];
          let lit = 0;
          for (const s of strips) for (let i = 0; i < s.data.length; i += 4)
            if (s.data[i] !== 246 || s.data[i + 1] !== 246 || s.data[i + 2] !== 244) lit++;
          return lit;
        });"""
    select = Select(browser.find_element("id", "clip-window"))
    frames = int(browser.find_element("id", "frame").get_attribute("max")) + 1
    for window in range(len(select.options)):
        select.select_by_index(window)
        for turn in (30, 120):
            browser.execute_script(
                f"var t = document.getElementById('turn'); t.value = {turn};"
                "t.dispatchEvent(new Event('input'));"
            )
            for frame in range(frames):
                browser.execute_script(
                    f"var s = document.getElementById('frame'); s.value = {frame};"
                    "s.dispatchEvent(new Event('input'));"
                )
                assert browser.execute_script(edges) == [0] * len(
                    browser.find_elements("css selector", "#viewer canvas")
                ), (window, turn, frame)
    panels = [
        c.get_attribute("data-panel")
        for c in browser.find_elements("css selector", "#viewer canvas")
    ]
    assert panels[:2] == ["ground truth", "repeat_last"]
    captions = browser.find_elements("css selector", "#viewer figcaption")
    assert "repeat_last: mean vertex error" in captions[1].text


def test_the_json_download_holds_the_rows_shown_with_the_protocol(browser, site):
    import urllib.parse

    summary = json.loads((site.parent / "results" / "cmu" / "all" / "summary.json").read_text())
    _open(browser, site / "table-cmu-all.html")
    href = browser.find_element("id", "download-json").get_attribute("href")
    table = json.loads(urllib.parse.unquote(href.split(",", 1)[1]))
    view = summary["views"][0]
    assert table["protocol_id"] == summary["protocol_id"] and table["metric"] == view["metric"]
    stored = {m["model"]: m["values"] for m in view["models"] if "@" not in m["model"]}
    assert {r["model"]: r["values"] for r in table["rows"]} == stored


def test_each_row_says_when_it_was_computed_and_how_to_compute_it_again(browser, site):
    _open(browser, site / "table-cmu-all.html")
    cell = browser.find_element("css selector", "#board tr[data-model='pgbig'] td.source")
    assert not cell.is_displayed()  # on demand
    browser.find_element("id", "show-sources").click()
    cell = browser.find_element("css selector", "#board tr[data-model='pgbig'] td.source")
    command = cell.find_element("css selector", "code").text
    # a copy of the tables in a folder of one's own: its commands run from anywhere, into it
    folder = (site.parent / "results" / "cmu" / "all" / "pgbig").resolve()
    weights = REPO_ROOT / "weights" / "cmu" / "pgbig.safetensors"
    assert command == (f"zoo eval --weights {weights} --benchmark cmu --sampler all --out {folder}")
    stored = json.loads((RESULTS / "cmu" / "all" / "pgbig" / "protocol.json").read_text())
    assert cell.text.startswith(stored["provenance"]["created"][:10])
    baseline = browser.find_element("css selector", "#board tr[data-model='repeat_last'] td.source")
    assert "zoo eval --model repeat_last --benchmark cmu --sampler all" in baseline.text
    assert "src=1" in browser.execute_script("return location.hash")
    # authors' weights their licence keeps out: the line says to make them first
    _open(browser, site / "table-cmu50-all.html", "#src=1")
    authors = browser.find_element("css selector", "#board tr[data-model='pgbig'] td.source")
    assert "first make its weights, which their licence keeps out" in authors.text
    assert "zoo eval --weights" in authors.find_element("css selector", "code").text


def test_curves_take_a_log_scale_and_hide_the_baselines(browser, site):
    _open(browser, site / "table-cmu-all.html")
    ticks = (
        "return [...document.querySelectorAll('#curves text.tick[text-anchor=end]')]"
        ".map(t => t.textContent)"
    )
    browser.find_element("id", "log-scale").click()
    assert {"1", "10", "100"} <= set(browser.execute_script(ticks))
    browser.find_element("id", "hide-baselines").click()
    assert not browser.find_elements("css selector", "#curves g.series[data-series='repeat_last']")
    assert browser.find_elements("css selector", "#curves g.series[data-series='pgbig']")
    browser.find_element("id", "hide-baselines").click()
    assert browser.find_elements("css selector", "#curves g.series[data-series='repeat_last']")


def test_every_action_is_printed_beside_every_other_as_papers_do(browser, site):
    summary = json.loads((site.parent / "results" / "cmu" / "all" / "summary.json").read_text())
    view = summary["views"][0]
    _open(browser, site / "table-cmu-all.html")
    pgbig = next(m for m in view["models"] if m["model"] == "pgbig")
    last = view["horizons_ms"][-1]
    cells = _each(
        browser,
        f"#per-action tr[data-model='pgbig'] td[data-action][data-horizon='{last}']",
        "[e.dataset.action, text(e)]",
    )
    assert cells == [[a, f"{pgbig['per_action'][a][-1]:.2f}"] for a in summary["actions"]]
    assert _each(browser, "#per-action th.action", "text(e)") == summary["actions"]
    assert browser.find_elements("css selector", "#per-action tr.reported")


def test_ranks_count_from_the_lowest_whatever_the_order_shown(browser, site):
    _open(browser, site / "table-cmu-all.html")
    header = browser.find_element("css selector", "#board th[data-key='7']")
    header.click()  # the longest horizon is the default sort: this click turns it descending
    ranks = _each(browser, "#board tbody tr[data-model]", "text(e.querySelector('td.rank'))")
    assert ranks[0] != "1" and ranks[-1] == "1"


def test_timings_of_two_machines_in_one_column_name_their_machine(browser, site):
    """CMU's costs were timed on the Xeon (2 threads) and, for pgbig, on an AMD EPYC (1
    thread): each latency names its machine, whose list the note gives."""
    costs = json.loads((site.parent / "results" / "cmu" / "costs.json").read_text())
    _open(browser, site / "table-cmu-all.html")
    browser.find_element("id", "show-costs").click()
    note = browser.find_element("id", "cost-note").text
    latency = dict(
        _each(
            browser,
            "#board tbody tr[data-model]",
            "[e.dataset.model, text(e.querySelectorAll('td.cost')[2])]",
        )
    )
    marks = {m: v[-1] for m, v in latency.items() if v and v[-1] in "¹²³⁴⁵⁶⁷⁸⁹"}
    assert len(set(marks.values())) >= 2, latency  # two machines, two marks
    assert "do not compare" in note and note.count("¹") == 1 and note.count("²") == 1
    assert costs  # the committed cost cells this is about


def test_a_long_y_label_fits_beside_its_axis(browser, site):
    _open(browser, site / "table-cmu_anny_oi_low-stride5_strict.html")
    label = browser.find_element("css selector", "#curves text.label[transform]")
    box = browser.execute_script("return arguments[0].getBBox()", label)
    svg = browser.execute_script(
        "return document.querySelector('#curves svg').viewBox.baseVal.height"
    )
    assert box["width"] < svg  # rotated: its length runs along the axis's height
    assert label.get_attribute("textContent").startswith("RMSE")


def test_the_index_filters_its_models(browser, site):
    from selenium.webdriver.support.ui import Select

    _open(browser, site / "index.html")

    def shown():
        return {m for m in _each(browser, "ul.models li", "shown(e) && e.dataset.model") if m}

    everything = shown()
    Select(browser.find_element("id", "filter-representation")).select_by_value("mesh")
    assert "spectrhums" in shown() and "pgbig" not in shown()
    Select(browser.find_element("id", "filter-representation")).select_by_value("")
    Select(browser.find_element("id", "filter-kind")).select_by_value("baseline")
    baselines = {"repeat_last", "constant_velocity", "interpolate"}
    assert shown() <= baselines  # a baseline has a card only where it has published figures
    Select(browser.find_element("id", "filter-kind")).select_by_value("trained")
    assert shown() and not shown() & baselines
    Select(browser.find_element("id", "filter-kind")).select_by_value("")
    browser.find_element("id", "filter-name").send_keys("spgsn")
    assert shown() == {m for m in everything if "spgsn" in m}


def test_any_two_rows_are_compared_and_the_choice_reopens(browser, site):
    """spgsn against its ablation spgsn_1body is no pair a reader asks about first, but the page
    holds it: picked from the two lists, it alone shows, and its address reopens it."""
    from selenium.webdriver.support.ui import Select

    def shown(table):
        pairs = _each(
            browser,
            f"section.pair[data-table='{table}']",
            "shown(e) && [e.dataset.a, e.dataset.b]",
        )
        return [tuple(p) for p in pairs if p]

    page = site / "compare-cmu.html"
    _open(browser, page)
    first, other_table = shown("all"), shown("ltd8")
    assert ("ltd", "repeat_last") in first and ("spgsn", "spgsn_1body") not in first
    form = browser.find_element("css selector", "form.pair-pick[data-table='all']")
    Select(form.find_element("name", "a")).select_by_visible_text("spgsn_1body")
    Select(form.find_element("name", "b")).select_by_visible_text("spgsn")
    assert shown("all") == [("spgsn", "spgsn_1body")]
    assert shown("ltd8") == other_table  # a choice in one table leaves the other as it was
    fragment = browser.execute_script("return location.hash")
    browser.get("about:blank")  # a new document: a jump within one applies it on hashchange, later
    _open(browser, page, fragment)
    assert shown("all") == [("spgsn", "spgsn_1body")]
    form = browser.find_element("css selector", "form.pair-pick[data-table='all']")
    Select(form.find_element("name", "a")).select_by_visible_text("spgsn")
    assert "pick two different rows" in form.text and shown("all") == []
    form.find_element("name", "reader").click()
    assert shown("all") == first


def test_the_viewer_overlays_the_truth_plays_at_a_chosen_speed_and_groups_windows(browser, site):
    from selenium.webdriver.support.ui import Select

    from zoo.report.clips import Clips

    _open(browser, site / "meshes-cmu_anny_oi_low.html")
    clips = Clips.read(site.parent / "results" / "cmu_anny_oi_low" / "clips.npz")
    groups = [
        g.get_attribute("label")
        for g in browser.find_elements("css selector", "#clip-window optgroup")
    ]
    assert groups == list(dict.fromkeys(clips.actions or clips.sequences))
    last = int(browser.find_element("id", "frame").get_attribute("max"))
    browser.execute_script(
        f"var s = document.getElementById('frame'); s.value = {last};"
        "s.dispatchEvent(new Event('input'));"
    )
    pixels = "return [...document.querySelectorAll('#viewer canvas')].map(c => c.toDataURL());"
    before = browser.execute_script(pixels)
    browser.find_element("id", "overlay").click()
    after = browser.execute_script(pixels)
    overlaid = [
        c.get_attribute("data-panel")
        for c in browser.find_elements("css selector", "#viewer canvas[data-overlay='1']")
    ]
    assert overlaid == ["repeat_last", *sorted(clips.predictions)]  # not the truth's own panel
    assert after[0] == before[0] and all(a != b for a, b in zip(after[1:], before[1:]))
    browser.find_element("id", "play").click()
    viewer = browser.find_element("id", "viewer")
    normal = float(viewer.get_attribute("data-interval-ms"))
    Select(browser.find_element("id", "speed")).select_by_value("2")
    assert float(viewer.get_attribute("data-interval-ms")) == pytest.approx(normal / 2)
    assert normal == pytest.approx(1000 / clips.fps)
    browser.find_element("id", "play").click()
