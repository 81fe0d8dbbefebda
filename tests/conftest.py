"""Shared test fixtures."""

import ctypes
import os
import random
import signal
import subprocess
import sys
import tempfile
import traceback
import types
import warnings
from pathlib import Path

import pytest

import surgsplat  # noqa: F401  (before torch: sets OpenMP's wait policy, see surgsplat/__init__)

SHARED = Path(__file__).resolve().parents[1].parent / "shared"


def pytest_configure(config):
    """Under pytest-xdist (`make test` runs one worker per core), the workers share the cores:
    each gives torch and the native kernels its share of them, and so do the commands it runs
    in subprocesses, through OMP_NUM_THREADS."""
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    if workers > 1:
        from surgsplat.render.native import set_threads

        share = max(1, (os.cpu_count() or 1) // workers)
        os.environ["OMP_NUM_THREADS"] = str(share)
        set_threads(share)


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


@pytest.fixture(scope="session")
def moving_phantom(tmp_path_factory) -> Path:
    """The small 'pulling' phantom seen by the moving endoscope, generated once per session."""
    from surgsplat.data.phantom import PhantomConfig, generate_phantom

    return generate_phantom(PhantomConfig(preset="small", camera="moving"),
                            tmp_path_factory.mktemp("moving") / "small")


@pytest.fixture(scope="session")
def grasping_phantom(tmp_path_factory) -> Path:
    """The small 'grasping' phantom (the tool in every frame), generated once per session."""
    from surgsplat.data.phantom import PhantomConfig, generate_phantom

    return generate_phantom(PhantomConfig(preset="small", motion="grasping"),
                            tmp_path_factory.mktemp("grasping") / "small")


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


class CliTimeout(BaseException):
    """A command run in this process outlived its timeout (a hang); a BaseException so that no
    `except Exception` of the command swallows it."""


DEFAULT_WARNING_FILTERS = (("default", DeprecationWarning, "__main__"),
                           ("ignore", DeprecationWarning, None),
                           ("ignore", PendingDeprecationWarning, None),
                           ("ignore", ImportWarning, None),
                           ("ignore", ResourceWarning, None))
"""The warning filters of a fresh `python` (no -W, no PYTHONWARNINGS), the first one tried
first: a command run in this process shows on its stderr the warnings a subprocess would."""


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    sys.stderr.write(warnings.formatwarning(message, category, filename, lineno, line))


def _run_cli_in_process(args: tuple[str, ...], timeout: float) -> subprocess.CompletedProcess:
    """`surgsplat *args` through surgsplat.cli.main.main in this process, as the console script
    runs it: file descriptors 1 and 2 (Python's and native code's output alike) go to files,
    SystemExit gives the exit status, an uncaught exception prints its traceback and gives
    status 1 (as Python does), warnings print as in a fresh interpreter. The process state a
    command may change (argv, the SIGTERM handler, the excepthook, the commands typer
    registered, torch's and the kernels' threads, the global random generators) is put back."""
    import numpy as np
    import torch

    from surgsplat.cli import main as cli_main
    from surgsplat.render import native

    saved = dict(argv=sys.argv, commands=list(cli_main.app.registered_commands),
                 sigterm=signal.getsignal(signal.SIGTERM),
                 sigalrm=signal.getsignal(signal.SIGALRM), excepthook=sys.excepthook,
                 threads=torch.get_num_threads(),
                 native_threads=native.native_module().max_threads()
                 if native.native_module() is not None else None,
                 rng=(torch.random.get_rng_state(), np.random.get_state(), random.getstate()),
                 streams=(sys.stdout, sys.stderr), main=sys.modules["__main__"])

    def expire(signum, frame):
        raise CliTimeout(f"surgsplat {' '.join(args)}: still running after {timeout} s")

    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err, \
            warnings.catch_warnings():
        for stream in saved["streams"]:
            stream.flush()
        fds = os.dup(1), os.dup(2)
        os.dup2(out.fileno(), 1)
        os.dup2(err.fileno(), 2)
        sys.stdout = open(1, "w", encoding="utf-8", closefd=False, buffering=1)
        sys.stderr = open(2, "w", encoding="utf-8", errors="backslashreplace", closefd=False,
                          buffering=1)
        warnings.resetwarnings()
        for action, category, module in reversed(DEFAULT_WARNING_FILTERS):
            warnings.filterwarnings(action, category=category, module=module or "")
        warnings.showwarning = _show_warning
        sys.argv = ["surgsplat", *args]
        # click names the program after __main__: the console script's (no package) gives
        # `surgsplat`, as a user sees it, not pytest's `python -m pytest...`
        sys.modules["__main__"] = types.ModuleType("__main__")
        signal.signal(signal.SIGALRM, expire)
        signal.setitimer(signal.ITIMER_REAL, timeout)
        try:
            cli_main.main()
            returncode = 0
        except SystemExit as stop:
            if stop.code is None or isinstance(stop.code, int):
                returncode = stop.code or 0
            else:
                print(stop.code, file=sys.stderr)
                returncode = 1
        except Exception:  # noqa: BLE001  (what the interpreter does with an uncaught one)
            traceback.print_exc()
            returncode = 1
        finally:
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, saved["sigalrm"])
            sys.stdout.close()
            sys.stderr.close()
            ctypes.CDLL(None).fflush(None)  # what native code left in C's stdio buffers
            sys.stdout, sys.stderr = saved["streams"]
            for fd, saved_fd in zip((1, 2), fds):
                os.dup2(saved_fd, fd)
                os.close(saved_fd)
            sys.argv = saved["argv"]
            sys.modules["__main__"] = saved["main"]
            cli_main.app.registered_commands[:] = saved["commands"]
            signal.signal(signal.SIGTERM, saved["sigterm"])
            sys.excepthook = saved["excepthook"]
            torch.set_num_threads(saved["threads"])
            if saved["native_threads"] is not None:
                native.native_module().set_threads(saved["native_threads"])
            torch.random.set_rng_state(saved["rng"][0])
            np.random.set_state(saved["rng"][1])
            random.setstate(saved["rng"][2])
        out.seek(0)
        err.seek(0)
        stdout = out.read().decode("utf-8", errors="replace")
        stderr = err.read().decode("utf-8", errors="replace")
    return subprocess.CompletedProcess(["surgsplat", *args], returncode, stdout, stderr)


def run_cli(*args: str, process: bool = False, env: dict[str, str] | None = None,
            timeout: float = 300) -> subprocess.CompletedProcess:
    """`surgsplat *args`: its exit status, stdout and stderr as a CompletedProcess.

    By default in this process (see _run_cli_in_process): the same messages and exit status
    without a new interpreter importing torch each time. With `process=True`, or `env`
    (variables added to this environment), in a subprocess, for what needs its own process:
    environment variables read at import, `--threads` set before torch starts its threads,
    locks held by another process, signals. `timeout` seconds: a hang raises (the subprocess
    is killed: TimeoutExpired; in this process: CliTimeout)."""
    if not process and env is None:
        return _run_cli_in_process(args, timeout)
    return subprocess.run([sys.executable, "-m", "surgsplat.cli.main", *args],
                          capture_output=True, text=True, timeout=timeout,
                          env={**os.environ, **(env or {})})


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


@pytest.fixture(scope="session")
def cli():
    """cli(*args) runs `surgsplat *args` as the console script does and returns the
    CompletedProcess: its exit status and its output. In this process by default;
    cli(*args, process=True) (or env={...}) in a subprocess (see run_cli)."""
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
