"""report.html is a page people open in a browser, so it is tested in one: headless Chromium (Debian's
``chromium``, which scripts/setup.sh installs as root with apt-get) opens the report of a small diagnosis,
every ``<img>`` must load (``naturalWidth`` > 0, the size of the PNG the report names), no request may
leave the file (the page itself only: its images are data URIs, so the page keeps working when it is
mailed, moved without its folder or read from the calibrated FMU's ``documentation/``), and a full-page
screenshot is kept as a test artefact: ``$MAGLEV_TEST_ARTEFACTS/report.png``, by default
``build/test-artefacts/report.png`` (the test prints the path).

Chromium is driven through the DevTools protocol over ``--remote-debugging-pipe`` (fd 3 its input,
fd 4 its output, JSON messages ended by a NUL byte) with the standard library only. Its background
networking is off, and every host name resolves to nothing, so the checks see each request the page
attempts while none reaches the network. A second test shows the checker catches a broken image and
outside requests, on a copy of the report with those planted. Skips, with the reason, without chromium."""

from __future__ import annotations

import base64
import fcntl
import json
import os
import re
import select
import shutil
import signal
import subprocess
import time
from dataclasses import dataclass, field
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
CHROMIUM = next((p for p in (shutil.which("chromium"), shutil.which("chromium-browser")) if p), None)
pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="chromium is not installed (scripts/setup.sh installs Debian's"
                                                         " chromium as root): report.html not opened in a browser")
TIMEOUT = 60.0   # [s] for the whole visit of a page: Chromium's start, the load, the screenshot
WIDTH, HEIGHT = 1280, 900


class Chromium:
    """Headless Chromium and its DevTools protocol over a pipe: :meth:`call` sends a command (to the
    browser, or to a page's session) and returns its result; events are collected in :attr:`events`."""

    def __init__(self, profile: Path):
        def above_4(fd: int) -> int:   # so that the redirections below cannot overwrite one another
            high = fcntl.fcntl(fd, fcntl.F_DUPFD_CLOEXEC, 10)
            os.close(fd)
            return high

        to_chrome_r, self._w = os.pipe()
        self._r, from_chrome_w = os.pipe()
        to_chrome_r, from_chrome_w = above_4(to_chrome_r), above_4(from_chrome_w)
        args = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                "--no-default-browser-check", "--disable-background-networking", "--disable-component-update",
                "--disable-sync", "--disable-extensions", "--disable-dev-shm-usage", "--mute-audio",
                "--hide-scrollbars", "--force-device-scale-factor=1", f"--window-size={WIDTH},{HEIGHT}",
                # belt and braces: should the page ask for a host, it gets no answer and no proxy
                "--no-proxy-server", "--host-resolver-rules=MAP * ~NOTFOUND",
                f"--user-data-dir={profile}", "--remote-debugging-pipe", "about:blank"]
        # the pipe's ends become fds 3 and 4 of Chromium: bash's redirections, then exec (bash, as dash
        # takes one-digit file descriptors only)
        shell = f'exec "$0" "$@" 3<&{to_chrome_r} 4>&{from_chrome_w} {to_chrome_r}<&- {from_chrome_w}>&-'
        profile.mkdir(parents=True)                     # a new, empty profile
        self.stderr = profile.with_name(profile.name + ".stderr")
        with open(self.stderr, "wb") as err:
            self.proc = subprocess.Popen([shutil.which("bash") or "/bin/bash", "-c", shell, *args],
                                         pass_fds=(to_chrome_r, from_chrome_w), stdin=subprocess.DEVNULL,
                                         stdout=err, stderr=err, start_new_session=True)
        os.close(to_chrome_r)
        os.close(from_chrome_w)
        self._buf = b""
        self._id = 0
        self.events: list[dict] = []

    def _send(self, msg: dict) -> None:
        data = json.dumps(msg).encode() + b"\0"
        while data:
            data = data[os.write(self._w, data):]

    def _receive(self, deadline: float) -> dict:
        while b"\0" not in self._buf:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([self._r], [], [], left)[0]:
                raise TimeoutError(f"no answer from Chromium within {TIMEOUT} s: {self.log()}")
            chunk = os.read(self._r, 1 << 20)
            if not chunk:
                raise ConnectionError(f"Chromium closed its DevTools pipe: {self.log()}")
            self._buf += chunk
        msg, self._buf = self._buf.split(b"\0", 1)
        return json.loads(msg)

    def call(self, method: str, session: str | None = None, deadline: float | None = None, **params) -> dict:
        self._id += 1
        msg: dict = {"id": self._id, "method": method, "params": params}
        if session:
            msg["sessionId"] = session
        self._send(msg)
        deadline = deadline or time.monotonic() + TIMEOUT
        while True:
            reply = self._receive(deadline)
            if reply.get("id") == self._id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return reply["result"]
            if "method" in reply:
                self.events.append(reply)

    def wait_for(self, method: str, session: str, deadline: float) -> dict:
        """The first event ``method`` of ``session``, collected already or still to come."""
        while True:
            for e in self.events:
                if e["method"] == method and e.get("sessionId") == session:
                    return e
            reply = self._receive(deadline)
            if "method" in reply:
                self.events.append(reply)

    def log(self) -> str:
        return self.stderr.read_text(errors="replace")[-2000:] if self.stderr.exists() else ""

    def close(self) -> None:
        try:
            self._send({"id": 0, "method": "Browser.close", "params": {}})
            self.proc.wait(timeout=15)
        except (OSError, subprocess.TimeoutExpired):
            os.killpg(self.proc.pid, signal.SIGKILL)   # the session this test started, nothing else
            self.proc.wait()
        finally:
            os.close(self._w)
            os.close(self._r)


@dataclass
class Visit:
    """What Chromium saw of a page: its ``<img>`` elements, every request it attempted (but data
    URIs, only counted), failed loads."""
    url: str
    title: str
    images: list[dict]
    requests: list[str]
    inline: int
    failed: list[str]
    screenshot: bytes
    height: int
    problems: list[str] = field(default_factory=list)


IMAGES_JS = """Promise.all(Array.from(document.images).map(i => i.decode().catch(() => null))).then(() =>
  Array.from(document.images).map(i => ({alt: i.alt, src: i.getAttribute('src').slice(0, 80),
    complete: i.complete, width: i.naturalWidth, height: i.naturalHeight})))"""


def visit(page: Path, profile: Path) -> Visit:
    """Opens ``page`` in headless Chromium; returns what it loaded and requested, and a full-page
    screenshot. :attr:`Visit.problems` lists each broken image and each request other than the page
    itself and data URIs: empty for a page that works on its own."""
    url = page.resolve().as_uri()
    browser = Chromium(profile)
    try:
        deadline = time.monotonic() + TIMEOUT
        target = browser.call("Target.createTarget", url="about:blank", deadline=deadline)["targetId"]
        s = browser.call("Target.attachToTarget", targetId=target, flatten=True, deadline=deadline)["sessionId"]
        for domain in ("Network", "Page", "Runtime"):
            browser.call(f"{domain}.enable", s, deadline)
        nav = browser.call("Page.navigate", s, deadline, url=url)
        assert "errorText" not in nav, nav
        browser.wait_for("Page.loadEventFired", s, deadline)
        res = browser.call("Runtime.evaluate", s, deadline, expression=IMAGES_JS, awaitPromise=True,
                           returnByValue=True)
        images = res["result"]["value"]
        title = browser.call("Runtime.evaluate", s, deadline, expression="document.title",
                             returnByValue=True)["result"]["value"]
        size = browser.call("Page.getLayoutMetrics", s, deadline)["cssContentSize"]
        width, height = max(WIDTH, int(size["width"])), int(size["height"])
        shot = browser.call("Page.captureScreenshot", s, deadline, format="png", captureBeyondViewport=True,
                            clip={"x": 0, "y": 0, "width": width, "height": height, "scale": 1})
        # every request of the page (its session's Network domain), data URIs included
        requests = [e["params"]["request"]["url"] for e in browser.events if e["method"] == "Network.requestWillBeSent"]
        requests += [e["params"]["url"] for e in browser.events if e["method"] == "Network.webSocketCreated"]
        failed = [e["params"].get("errorText", "") for e in browser.events if e["method"] == "Network.loadingFailed"]
    finally:
        browser.close()
    inline = sum(r.startswith("data:") for r in requests)     # the data URIs: in the page, not fetched
    requests = [r for r in requests if not r.startswith("data:")]
    v = Visit(url, title, images, requests, inline, failed, base64.b64decode(shot["data"]), height)
    v.problems += [f"broken image {i['src']!r} (alt {i['alt']!r})" for i in images
                   if not i["complete"] or i["width"] == 0]
    v.problems += [f"request beyond the page: {r[:120]}" for r in requests if r != url]
    return v


def png_size(data: bytes) -> tuple[int, int]:
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and data[12:16] == b"IHDR", "not a PNG"
    return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")


def artefacts() -> Path:
    d = Path(os.environ.get("MAGLEV_TEST_ARTEFACTS") or REPO / "build" / "test-artefacts")
    d.mkdir(parents=True, exist_ok=True)
    return d


@pytest.fixture(scope="module")
def report(tmp_path_factory) -> Path:
    """The report of a 3 s record with a planted 3 ms delay, diagnosed for the delay alone (the
    plots and tables of a full report, in a few seconds): its folder."""
    from maglev_cosim.diagnosis import diagnose
    from maglev_cosim.records.record import read_record
    from maglev_cosim.records.synth import synth_record

    folder = tmp_path_factory.mktemp("report")
    rec = read_record(synth_record(folder / "rec.csv", effects={"delay": {"T_d": 0.003}}, reference="square",
                                   period=1.0, duration=3.0, seed=2))
    d = diagnose(rec, effects=["delay"], workers=1, out=folder / "diag")
    assert d.selected == ["delay"]
    return folder / "diag"


@pytest.mark.slow   # the quick tier's 2-minute budget: a diagnosis and a headless browser, 5-8 s
def test_report_html_renders_in_chromium_with_every_image_and_no_outside_request(report, tmp_path, capsys):
    """The report of :func:`report` in Chromium: its figures decoded at their PNG's size, no request
    but the page itself, and a full-page screenshot with text and plots, kept as an artefact."""
    v = visit(report / "report.html", tmp_path / "profile")
    out = artefacts() / "report.png"
    out.write_bytes(v.screenshot)
    with capsys.disabled():
        print(f"\n[test_report_browser] screenshot of report.html in {CHROMIUM}: {out}")
    assert v.problems == [], v.problems
    assert v.requests == [v.url] and v.failed == []          # the page itself, nothing else
    assert v.inline == len(v.images)                          # and its images, as data URIs
    assert v.title.startswith("Diagnosis of ")
    # every figure the Markdown report names, decoded at the size of its PNG
    from PIL import Image

    named = [ln[2:ln.index("]")] for ln in (report / "report.md").read_text().splitlines() if ln.startswith("![")]
    assert len(named) >= 5 and [i["alt"] for i in v.images] == named
    for i in v.images:
        assert i["src"].startswith("data:image/png;base64,"), i
        with Image.open(report / i["alt"]) as png:
            assert (i["width"], i["height"]) == png.size, i
    # the screenshot of the whole page (kept above, also when a check fails): not a blank page
    w, h = png_size(v.screenshot)
    assert w == WIDTH and h == v.height > 2000 and len(v.screenshot) > 100_000
    with Image.open(out) as shot:    # text and plots: many colours, white not all
        rgb = shot.convert("RGB")
        colours = rgb.getcolors(maxcolors=1 << 20)
        assert colours is not None and len(colours) > 1000
        white = max(colours)[0] / (w * h)
        assert 0.3 < white < 0.98, white


@pytest.mark.slow   # the quick tier's 2-minute budget: the report fixture's diagnosis (5 s)
def test_the_checker_catches_a_broken_image_and_outside_requests(report, tmp_path):
    """A copy of the report with its first image's source a file that is not there, its second an
    outside address, and an outside style sheet: each is reported."""
    html = (report / "report.html").read_text()
    first, second = list(re.finditer(r'src="data:image/png;base64,[^"]*"', html))[:2]
    broken = (html[:first.start()] + 'src="missing.png"' + html[first.end():second.start()]
              + 'src="https://example.invalid/x.png"' + html[second.end():])
    broken = broken.replace("</head>", '<link rel="stylesheet" href="http://fonts.example.invalid/f.css"></head>')
    page = tmp_path / "broken" / "report.html"
    page.parent.mkdir()
    page.write_text(broken)
    v = visit(page, tmp_path / "profile")
    bad = [i for i in v.images if i["width"] == 0]
    assert [i["src"] for i in bad] == ["missing.png", "https://example.invalid/x.png"]
    assert len(v.images) - len(bad) >= 3                      # the others still load
    assert sorted(p.split(" ")[0] for p in v.problems) == ["broken"] * 2 + ["request"] * 3, v.problems
    outside = [r for r in v.requests if r != v.url]
    assert sorted(outside) == sorted([(page.parent / "missing.png").as_uri(), "https://example.invalid/x.png",
                                      "http://fonts.example.invalid/f.css"])
