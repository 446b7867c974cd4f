"""Fixtures: the repository, the `aift` binary to compare with, a calibration cache shared by the
CLI and Python within one test session."""

import os
import pathlib
import subprocess

import pytest

REPO = pathlib.Path(__file__).resolve().parents[2]


@pytest.fixture(scope="session")
def repo():
    return REPO


@pytest.fixture(scope="session")
def aift_bin():
    path = pathlib.Path(os.environ.get("AIFT_BIN", REPO / "target" / "release" / "aift"))
    if not path.is_file():
        pytest.fail(f"the aift binary {path} is missing: build it with `cargo build --release` or set AIFT_BIN")
    return path


@pytest.fixture(scope="session", autouse=True)
def cache_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("aift-cache")
    os.environ["AIFT_CACHE_DIR"] = str(d)
    return d


@pytest.fixture
def cli(aift_bin):
    def run(*args, check=True):
        p = subprocess.run([str(aift_bin), *map(str, args)], capture_output=True, text=True,
                           env=dict(os.environ))
        if check and p.returncode != 0:
            raise AssertionError(f"aift {' '.join(map(str, args))} exited {p.returncode}:\n{p.stderr}")
        return p
    return run


@pytest.fixture(scope="session")
def tiny_campaign(repo):
    """A campaign file's text on the paper arm: freezes while moving on `channels`, 9 s on the
    articulated engine, one seed (as tests/common/mod.rs's tiny_campaign)."""
    def text(name, methods=("no-ft", "oracle"), channels=("enc*",)):
        quoted = lambda xs: "[" + ", ".join(f'"{x}"' for x in xs) + "]"
        return f"""
name = "{name}"
seeds = 1
methods = {quoted(methods)}
defaults = {{ duration = 9.0, plant = {{ engine = "articulated" }} }}
channels = {quoted(channels)}

[[arms]]
name = "paper"
scenario = "{repo / 'assets/scenarios/paper_healthy.toml'}"

[[kinds]]
kind = "freeze"
onsets = ["moving"]
"""
    return text


@pytest.fixture
def interrupted():
    """Runs `call` with a SIGINT sent to this process after 0.5 s and expects KeyboardInterrupt.
    Ctrl-C's handler is set here, as an interactive session has it: a process started in the
    background by a non-interactive shell inherits SIGINT ignored, and Python then installs no
    handler (the tests failed under `tools/test.sh &` without this)."""
    import signal
    import threading

    def run(call):
        previous = signal.signal(signal.SIGINT, signal.default_int_handler)
        timer = threading.Timer(0.5, lambda: os.kill(os.getpid(), signal.SIGINT))
        timer.start()
        try:
            with pytest.raises(KeyboardInterrupt):
                call()
        finally:
            timer.cancel()
            signal.signal(signal.SIGINT, previous)

    return run

