"""A page opened in headless Chromium, driven over the DevTools protocol (what a person sees).

``HeadlessPage(path)`` starts Debian's ``chromium`` with remote debugging on loopback, opens the
file, and collects console messages and uncaught exceptions; ``evaluate`` runs JavaScript in the
page (promises awaited), ``screenshot`` returns a PNG of the whole page. Bounded in time; the
browser is killed on close.
"""
from __future__ import annotations

import base64
import itertools
import json
import re
import shutil
import subprocess
import time
import urllib.request
from pathlib import Path
from typing import Any

from websockets.sync.client import connect


def chromium() -> str | None:
    return shutil.which("chromium") or shutil.which("chromium-browser")


class HeadlessPage:
    def __init__(self, path: Path, profile_dir: Path, timeout_s: float = 30.0) -> None:
        self.timeout_s = timeout_s
        self.console: list[str] = []
        self.errors: list[str] = []
        self._ids = itertools.count(1)
        self._browser = subprocess.Popen(
            [chromium(), "--headless", "--no-sandbox", "--disable-gpu", "--remote-debugging-address=127.0.0.1",
             "--remote-debugging-port=0", f"--user-data-dir={profile_dir}", "--autoplay-policy=no-user-gesture-required",
             "--window-size=1400,1000", "about:blank"],
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        try:
            port = self._devtools_port()
            deadline = time.monotonic() + timeout_s
            page = None
            while page is None and time.monotonic() < deadline:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=5) as answer:
                    page = next((t for t in json.load(answer) if t["type"] == "page"), None)
            assert page is not None, "Chromium opened no page"
            self._ws = connect(page["webSocketDebuggerUrl"], open_timeout=timeout_s, max_size=None)
            for domain in ("Page", "Runtime", "Log"):
                self.call(f"{domain}.enable")
            self.call("Page.navigate", url=path.resolve().as_uri())
            self._wait_for("Page.loadEventFired")
        except BaseException:
            self.close()
            raise

    def _devtools_port(self) -> int:
        deadline = time.monotonic() + self.timeout_s
        assert self._browser.stderr is not None
        while time.monotonic() < deadline:
            line = self._browser.stderr.readline()
            found = re.search(r"DevTools listening on ws://127\.0\.0\.1:(\d+)/", line)
            if found:
                return int(found.group(1))
            if not line and self._browser.poll() is not None:
                break
        raise RuntimeError("Chromium did not start its DevTools server")

    def _note(self, event: dict[str, Any]) -> None:
        method, params = event.get("method"), event.get("params", {})
        if method == "Runtime.consoleAPICalled":
            text = " ".join(str(a.get("value", a.get("description", ""))) for a in params.get("args", []))
            self.console.append(f"{params.get('type')}: {text}")
            if params.get("type") in ("error", "assert"):
                self.errors.append(text)
        elif method == "Runtime.exceptionThrown":
            details = params.get("exceptionDetails", {})
            self.errors.append(details.get("exception", {}).get("description", details.get("text", "")))
        elif method == "Log.entryAdded" and params.get("entry", {}).get("level") == "error":
            entry = params["entry"]
            self.errors.append(f"{entry.get('source')}: {entry.get('text')} {entry.get('url', '')}".strip())

    def _receive(self, deadline: float) -> dict[str, Any]:
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            raise TimeoutError("the page did not answer in time")
        message = json.loads(self._ws.recv(timeout=remaining))
        self._note(message)
        return message

    def _wait_for(self, method: str) -> dict[str, Any]:
        deadline = time.monotonic() + self.timeout_s
        while True:
            message = self._receive(deadline)
            if message.get("method") == method:
                return message

    def call(self, method: str, **params: Any) -> dict[str, Any]:
        call_id = next(self._ids)
        self._ws.send(json.dumps({"id": call_id, "method": method, "params": params}))
        deadline = time.monotonic() + self.timeout_s
        while True:
            message = self._receive(deadline)
            if message.get("id") == call_id:
                if "error" in message:
                    raise RuntimeError(f"{method}: {message['error']}")
                return message.get("result", {})

    def evaluate(self, expression: str) -> Any:
        result = self.call("Runtime.evaluate", expression=expression, awaitPromise=True, returnByValue=True)
        if "exceptionDetails" in result:
            raise RuntimeError(f"the page's script failed: {result['exceptionDetails']}")
        return result["result"].get("value")

    def screenshot(self) -> bytes:
        shot = self.call("Page.captureScreenshot", format="png", captureBeyondViewport=True)
        return base64.b64decode(shot["data"])

    def close(self) -> None:
        ws = getattr(self, "_ws", None)
        if ws is not None:
            ws.close()
        self._browser.kill()
        self._browser.wait(timeout=10)
        if self._browser.stderr is not None:
            self._browser.stderr.close()

    def __enter__(self) -> "HeadlessPage":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
