"""Shared test fixtures."""

import subprocess
import sys
from pathlib import Path

import pytest

import surgsplat  # noqa: F401  (before torch: sets OpenMP's wait policy, see surgsplat/__init__)

SHARED = Path(__file__).resolve().parents[1].parent / "shared"


@pytest.fixture
def shared_data() -> Path:
    """The real data samples beside the repository; skips the test when they are absent."""
    data = SHARED / "data"
    if not data.is_dir():
        pytest.skip(f"real data samples not found at {data}")
    return data


@pytest.fixture(scope="session")
def small_phantom(tmp_path_factory) -> Path:
    """The small 'pulling' phantom (160x128, 16 frames), generated once per test session."""
    from surgsplat.data.phantom import PhantomConfig, generate_phantom

    return generate_phantom(PhantomConfig(preset="small", motion="pulling"),
                            tmp_path_factory.mktemp("phantom") / "small")


@pytest.fixture(params=["avx512", "avx2", "baseline", "neon"])
def native_isa(request) -> str:
    """Runs the test once per ISA variant of the native kernels, with that variant in use;
    skips the variants this machine lacks (not built, or the CPU cannot run them)."""
    from surgsplat.render import native

    reason = native.isa_unavailable(request.param)
    if reason is not None:
        pytest.skip(reason)
    native.use_isa(request.param)
    yield request.param
    native.use_isa(None)


def run_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "surgsplat.cli.main", *args],
                          capture_output=True, text=True, timeout=300)


def one_error_line(result: subprocess.CompletedProcess) -> str:
    """The single `error: ...` line a failed command printed (exit status 2, no traceback)."""
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert result.returncode == 2 and "Traceback" not in result.stderr, result.stderr
    assert len(lines) == 1 and lines[0].startswith("error:"), result.stderr
    return lines[0]


@pytest.fixture(name="one_error_line")
def one_error_line_fixture():
    """one_error_line(result): the one error line of a failed command, checked."""
    return one_error_line


@pytest.fixture
def cli():
    """cli(*args) runs `surgsplat *args` as a user does (a subprocess) and returns the
    CompletedProcess: its exit status and its output."""
    return run_cli


class HeadlessBrowser:
    """Debian's chromium, headless, driven over the Chrome DevTools Protocol (no driver to
    download): open a page, wait, collect console errors, take a screenshot."""

    def __init__(self, executable: str, tmp: Path):
        import socket

        with socket.socket() as probe:
            probe.bind(("127.0.0.1", 0))
            self.port = probe.getsockname()[1]
        self.process = subprocess.Popen(
            [executable, "--headless=new", "--no-sandbox", "--use-angle=swiftshader",
             "--enable-unsafe-swiftshader", f"--remote-debugging-port={self.port}",
             f"--user-data-dir={tmp}", "--window-size=1200,800", "about:blank"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)

    def _page_socket(self) -> str:
        import json
        import time
        import urllib.request

        for _ in range(100):
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{self.port}/json/list") as reply:
                    pages = [p for p in json.load(reply) if p["type"] == "page"]
                if pages:
                    return pages[0]["webSocketDebuggerUrl"]
            except OSError:
                pass
            time.sleep(0.2)
        raise RuntimeError("chromium's DevTools endpoint did not come up")

    def visit(self, url: str, seconds: float, until=None,
              settle: float = 0.5) -> tuple[bytes, list[str]]:
        """Open url, wait `seconds` (or until `until()` is true, at most `seconds`), then
        `settle` more seconds; return the PNG screenshot and the console errors and exceptions
        seen."""
        import base64
        import json
        import time

        from websockets.sync.client import connect

        errors: list[str] = []
        with connect(self._page_socket(), max_size=None) as socket:
            counter = iter(range(1, 10**6))

            def call(method: str, **params):
                ident = next(counter)
                socket.send(json.dumps({"id": ident, "method": method, "params": params}))
                while True:
                    message = json.loads(socket.recv())
                    collect(message)
                    if message.get("id") == ident:
                        return message.get("result", {})

            def collect(message: dict) -> None:
                method, params = message.get("method"), message.get("params", {})
                if method == "Runtime.exceptionThrown":
                    errors.append(str(params.get("exceptionDetails", {}).get("text")))
                elif method == "Runtime.consoleAPICalled" and params.get("type") == "error":
                    errors.append(" ".join(str(a.get("value", a.get("description")))
                                           for a in params.get("args", [])))
                elif method == "Log.entryAdded" and params["entry"]["level"] == "error":
                    errors.append(params["entry"]["text"])

            for domain in ("Page.enable", "Runtime.enable", "Log.enable"):
                call(domain)
            call("Page.navigate", url=url)
            deadline = time.monotonic() + seconds
            while time.monotonic() < deadline and not (until and until()):
                try:
                    collect(json.loads(socket.recv(timeout=0.2)))
                except TimeoutError:
                    pass
            settled = time.monotonic() + settle
            while time.monotonic() < settled:
                try:
                    collect(json.loads(socket.recv(timeout=0.2)))
                except TimeoutError:
                    pass
            shot = call("Page.captureScreenshot", format="png")
        return base64.b64decode(shot["data"]), errors

    def close(self) -> None:
        self.process.terminate()
        self.process.wait(timeout=10)


@pytest.fixture
def browser(tmp_path):
    """A headless chromium (skips the test when chromium is not installed)."""
    import shutil

    executable = shutil.which("chromium") or shutil.which("chromium-browser")
    if executable is None:
        pytest.skip("chromium is not installed (.ci/run installs it)")
    instance = HeadlessBrowser(executable, tmp_path / "chromium-profile")
    yield instance
    instance.close()
