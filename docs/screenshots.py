"""Screenshots of the web console for docs/web.md: a demo server, a headless Chromium, PNGs in docs/img/.

    .venv/bin/python docs/screenshots.py            # needs /usr/bin/chromium (Debian: apt-get install chromium)
    .venv/bin/python docs/screenshots.py --no-video # skip recording the demo episode video (8 s faster)

The server runs on a temporary data directory filled by ``proxybench.server.web.demo.seed_demo`` (invented
results entered through the API); the browser is Debian's Chromium driven by Playwright (no browser
download). Each PNG is reduced to a 256-colour palette so that it stays small enough to commit.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from PIL import Image

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]
#: seek every <video> to 2 s and wait until that frame is shown (else the screenshot shows a spinner)
SHOW_VIDEO_FRAME = """() => Promise.all(Array.from(document.querySelectorAll("video")).map(v => new Promise(done => {
  v.addEventListener("seeked", done, {once: true}); v.addEventListener("error", done, {once: true});
  if (v.readyState >= 1) { v.currentTime = 2; }
  else { v.addEventListener("loadedmetadata", () => { v.currentTime = 2; }); }
}))).then(shown => shown.length)"""
MAX_BYTES = 200_000
MAX_HEIGHT = 2200  # px: a longer page is cut (the top is what the docs show)


def demo_video(workdir: Path) -> bytes:
    """A real 6 s episode of the ``vision`` agent (camera beside top-down), as the evaluator records it."""
    from proxybench.agents import make_agent
    from proxybench.domain.params import DomainParams
    from proxybench.runner.jobs import DomainSpec
    from proxybench.runner.record import record_run

    params = DomainParams(image_width=160, image_height=120).model_dump(mode="json")
    rec = record_run(DomainSpec("simulation", params), make_agent("vision"), "loop_3x3", 3, 6.0, workdir / "episode",
                     strip_frames=2)
    return next(f for f in rec.files if f.suffix == ".mp4").read_bytes()


def shrink(path: Path) -> int:
    """Cut to ``MAX_HEIGHT`` and store as a palette PNG (fewer colours until under ``MAX_BYTES``)."""
    image = Image.open(path).convert("RGB")
    if image.height > MAX_HEIGHT:
        image = image.crop((0, 0, image.width, MAX_HEIGHT))
    for colors in (256, 128, 64, 32):
        image.quantize(colors=colors, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE).save(
            path, optimize=True)
        if path.stat().st_size <= MAX_BYTES:
            break
    return path.stat().st_size


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, default=Path(__file__).with_name("img"))
    parser.add_argument("--no-video", action="store_true", help="do not record the demo episode video")
    args = parser.parse_args()

    from fastapi.testclient import TestClient
    from playwright.sync_api import sync_playwright

    from proxybench.server.app import create_app
    from proxybench.server.config import Settings
    from proxybench.server.web.demo import seed_demo, serve_in_thread

    args.out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        app = create_app(Settings(data_dir=Path(tmp) / "server"))
        video = None if args.no_video else demo_video(Path(tmp))
        with TestClient(app) as client:
            demo = seed_demo(client, app.state.admin_token, video=video)
        sub = demo.submissions
        shots = [  # (file, user, path, full page)
            ("overview", "admin", "/", False),
            ("benchmarks", "admin", "/benchmarks", False),
            ("benchmark", "admin", "/benchmarks/aido_lf", True),
            ("leaderboard", "alice", "/leaderboards/aido_lf", False),
            ("leaderboard-hidden", "admin", "/leaderboards/aido_lf?split=hidden", False),
            ("submission", "bob", f"/submissions/{sub['vision v2']}", True),
            ("jobs", "admin", "/jobs", False),
            ("evaluators", "admin", "/evaluators", False),
            ("operator", "admin", "/operator", True),
            ("forbidden", "alice", f"/submissions/{sub['vision v2']}", False),
        ]
        with serve_in_thread(app) as url, sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
            page = browser.new_page(viewport={"width": 1280, "height": 820})
            page.goto(url + "/login")
            page.screenshot(path=args.out / "login.png")
            print(f"login.png {shrink(args.out / 'login.png')} bytes")
            who = None
            for name, user, path, full in shots:
                if user != who:
                    page.goto(url + "/login")
                    page.fill("#token", demo.tokens[user])
                    page.click("form[action='/login'] button")
                    page.wait_for_url(url + "/")
                    who = user
                page.goto(url + path)
                page.wait_for_load_state("networkidle")
                if page.evaluate(SHOW_VIDEO_FRAME):
                    page.wait_for_timeout(500)  # let the player's loading spinner fade out
                target = args.out / f"{name}.png"
                page.screenshot(path=target, full_page=full)
                print(f"{target.name} {shrink(target)} bytes")
            browser.close()


if __name__ == "__main__":
    main()
