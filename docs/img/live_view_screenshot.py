"""Make ``docs/img/live-view.png``: ``examples/live-view.html`` in headless Chromium, connected
to ``examples/live_demo.py`` streaming through the daemon's live view.

    .venv/bin/python docs/img/live_view_screenshot.py [--seconds 20] [--chromium /usr/bin/chromium]

Starts the demo on a free port, opens the page (a file, ``?url=ws://127.0.0.1:PORT``) in
Debian's Chromium with a DevTools port, lets it receive for ``--seconds`` of real time (the
page's WebSocket is live: ``--screenshot`` with a virtual time budget would not let it
connect) and saves ``Page.captureScreenshot`` as PNG. Chromium runs headless with the flags of
the machine notes (no sandbox as root, no background networking) and a fresh profile.
"""

from __future__ import annotations

import argparse
import base64
import contextlib
import json
import subprocess
import sys
import tempfile
import time
import urllib.request
from collections.abc import Sequence
from pathlib import Path

from websockets.sync.client import connect

ROOT = Path(__file__).resolve().parents[2]
OUT = ROOT / "docs" / "img" / "live-view.png"
FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--hide-scrollbars",
    "--remote-debugging-port=0",
]


def devtools_port(profile: Path, timeout_s: float = 20.0) -> int:
    """The port Chromium wrote to ``DevToolsActivePort`` in its profile."""
    deadline = time.monotonic() + timeout_s
    f = profile / "DevToolsActivePort"
    while time.monotonic() < deadline:
        if f.exists() and f.read_text().strip():
            return int(f.read_text().split()[0])
        time.sleep(0.1)
    raise RuntimeError("chromium did not open its DevTools port")


class HeadlessChromium:
    """A headless Chromium (``FLAGS``, a fresh ``profile`` directory) on ``about:blank``,
    driven over its DevTools protocol: :meth:`call` sends one command to its page and returns
    the result (an error answer raises). ``prefix`` runs before the binary (``chrt -i 0``)."""

    def __init__(
        self, chromium: str, profile: Path, size: str = "1280,900", prefix: Sequence[str] = ()
    ) -> None:
        self.proc = subprocess.Popen(
            [*prefix, chromium, *FLAGS, f"--user-data-dir={profile}",
             f"--window-size={size}", "about:blank"],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )  # fmt: skip
        try:
            port = devtools_port(profile)
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=10) as r:
                target = next(t for t in json.load(r) if t["type"] == "page")
            self._stack = contextlib.ExitStack()
            self._cdp = self._stack.enter_context(
                connect(target["webSocketDebuggerUrl"], max_size=None)
            )
        except BaseException:
            self.proc.kill()
            self.proc.wait(10)
            raise
        self._ids = iter(range(1, 1 << 62))

    def call(self, method: str, **params: object) -> dict[str, object]:
        mid = next(self._ids)
        self._cdp.send(json.dumps({"id": mid, "method": method, "params": params}))
        while True:
            msg = json.loads(self._cdp.recv(timeout=30))
            if msg.get("id") == mid:
                if "error" in msg:
                    raise RuntimeError(f"{method}: {msg['error']}")
                return msg.get("result", {})  # type: ignore[no-any-return]

    def close(self) -> None:
        self._stack.close()
        self.proc.terminate()
        self.proc.wait(10)


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--chromium", default="/usr/bin/chromium")
    parser.add_argument("--size", default="1400,900")
    parser.add_argument("-o", "--out", default=str(OUT))
    args = parser.parse_args(argv)
    demo = subprocess.Popen(
        [sys.executable, str(ROOT / "examples" / "live_demo.py"), "--port", "0", "--rate-hz", "40"],
        stdout=subprocess.PIPE,
        text=True,
    )
    assert demo.stdout is not None
    with tempfile.TemporaryDirectory() as tmp:
        browser = None
        try:
            line = demo.stdout.readline()
            if "streaming on ws://" not in line:
                raise RuntimeError(f"demo did not start: {line!r}")
            url = line.split()[2]
            page = f"{(ROOT / 'examples' / 'live-view.html').as_uri()}?url={url}"
            browser = HeadlessChromium(args.chromium, Path(tmp), args.size)
            browser.call("Page.navigate", url=page)
            time.sleep(args.seconds)
            shot = browser.call("Page.captureScreenshot", format="png")
            Path(args.out).write_bytes(base64.b64decode(str(shot["data"])))
            print(f"wrote {args.out}")
        finally:
            if browser is not None:
                browser.close()
            demo.terminate()
            demo.wait(10)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
