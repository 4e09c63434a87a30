"""The task pool under attack and accident: workers die with their parent; Dask scheduler
addresses and TLS options are checked before any work; TLS works end to end."""

from __future__ import annotations

import logging
import math
import shutil
import signal
import subprocess
import sys
import textwrap
import time

import pytest
from typer.testing import CliRunner

from espin.cli import app
from espin.core.cluster import tls_security
from espin.core.errors import ConfigError
from espin.core.parallel import TaskPool, check_scheduler, parallel_map

SECRET = "do-not-print-me"

POOL_SCRIPT = textwrap.dedent("""
    import time

    from espin.core.parallel import TaskPool

    if __name__ == "__main__":
        with TaskPool(workers=2, blas_threads=None) as pool:
            for outcome in pool.map(time.sleep, [0, 60]):  # one worker idle, one busy for a minute
                print("running", flush=True)
""")


def _running(process) -> bool:
    """True while ``process`` (a psutil.Process) runs; a zombie waiting to be reaped has ended."""
    import psutil

    try:
        return process.status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False


@pytest.mark.skipif(sys.platform == "win32", reason="SIGKILL")
def test_workers_exit_when_their_parent_is_killed(tmp_path):
    """kill -9 of the process that runs a pool (its tasks cannot be told): every worker ends."""
    psutil = pytest.importorskip("psutil")
    script = tmp_path / "pool.py"
    script.write_text(POOL_SCRIPT)
    parent = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True)
    children = []
    try:
        assert parent.stdout.readline().strip() == "running"
        children = psutil.Process(parent.pid).children(recursive=True)
        workers = [c for c in children if "spawn_main" in " ".join(c.cmdline())]
        assert len(workers) == 2, [c.cmdline() for c in children]
        parent.send_signal(signal.SIGKILL)
        parent.wait()
        deadline = time.monotonic() + 5
        while any(map(_running, children)) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not [c.pid for c in children if _running(c)]
    finally:
        parent.kill()
        parent.wait()
        for child in children:
            if _running(child):
                child.kill()


@pytest.mark.parametrize("scheduler", [
    "myhost:8786", "tcp://myhost", "http://myhost:8786", "tcp://myhost:0", "tcp://myhost:65536",
    "tcp://myhost:8786/path", "tcp://my host:8786", "tcp://::1:8786", "", 8786,
])
def test_bad_scheduler_refused_before_any_work(scheduler):
    with pytest.raises(ConfigError, match="scheduler"):
        TaskPool(scheduler=scheduler)


@pytest.mark.parametrize("scheduler", [None, "local", "tcp://127.0.0.1:8786", "tcp://[::1]:8786",
                                       "tcp://node-7.cluster.example:8786"])
def test_good_scheduler_accepted(scheduler):
    check_scheduler(scheduler)


def test_tls_address_needs_the_tls_files():
    with pytest.raises(ConfigError, match="tls-ca-file"):
        TaskPool(scheduler="tls://node-7:8786")


def test_tls_options_only_with_a_tls_address(tmp_path):
    pem = tmp_path / "any.pem"
    pem.write_text("placeholder")
    security = tls_security(pem, pem)
    for scheduler in (None, "local", "tcp://node-7:8786"):
        with pytest.raises(ConfigError, match="security"):
            TaskPool(scheduler=scheduler, security=security)
    with pytest.raises(ConfigError, match="security"):
        TaskPool(scheduler="tls://node-7:8786", security={"tls_ca_file": str(pem)})
    TaskPool(scheduler="tls://node-7:8786", security=security)  # nothing connects before a task


@pytest.mark.parametrize("scheduler, warns", [
    ("tcp://192.0.2.10:8786", True), ("tcp://node-7.cluster.example:8786", True),
    ("tcp://127.0.0.1:8786", False), ("tcp://localhost:8786", False), ("tcp://[::1]:8786", False),
    ("local", False),
])
def test_unencrypted_scheduler_on_another_machine_warns(caplog, scheduler, warns):
    with caplog.at_level(logging.WARNING, logger="espin.core.parallel"):
        TaskPool(scheduler=scheduler)  # lazy: no connection is attempted
    messages = [r.getMessage() for r in caplog.records]
    assert bool(messages) == warns, messages
    if warns:
        assert "unencrypted" in messages[0] and "trust" in messages[0] and scheduler in messages[0]


def test_tls_security_from_the_files(tmp_path):
    from distributed.security import Security

    ca, cert, key = (tmp_path / name for name in ("ca.pem", "cert.pem", "key.pem"))
    for path in (ca, cert, key):
        path.write_text(f"-----BEGIN PRIVATE KEY-----\n{SECRET}\n")
    assert tls_security() is None
    security = tls_security(ca, cert, key)
    assert isinstance(security, Security) and security.require_encryption
    assert (security.tls_ca_file, security.tls_client_cert, security.tls_client_key) == (str(ca), str(cert), str(key))
    assert tls_security(ca, cert).tls_client_key is None  # the certificate file may hold the key
    for files, option in [((None, cert, key), "tls_ca_file"), ((ca, None, key), "tls_cert"),
                          ((None, None, key), "tls_ca_file")]:
        with pytest.raises(ConfigError, match=option) as error:
            tls_security(*files)
        assert SECRET not in str(error.value)
    missing = tmp_path / "missing.pem"
    for files, option, bad in [((missing, cert, key), "--tls-ca-file", missing),
                               ((ca, missing, key), "--tls-cert", missing),
                               ((ca, cert, missing), "--tls-key", missing),
                               ((ca, tmp_path, key), "--tls-cert", tmp_path)]:
        with pytest.raises(ConfigError, match=option) as error:
            tls_security(*files)
        assert str(bad) in str(error.value) and SECRET not in str(error.value)


def _self_signed(folder):
    """A certificate (its own CA) and its key, from the openssl command."""
    cert, key = folder / "cert.pem", folder / "key.pem"
    subprocess.run(["openssl", "req", "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1",
                    "-nodes", "-keyout", str(key), "-out", str(cert), "-days", "1", "-subj", "/CN=localhost",
                    "-addext", "basicConstraints=critical,CA:TRUE",
                    "-addext", "keyUsage=keyCertSign,digitalSignature,keyEncipherment"],
                   check=True, capture_output=True)
    return cert, key


@pytest.mark.skipif(shutil.which("openssl") is None, reason="needs the openssl command")
def test_tasks_run_on_a_tls_scheduler(tmp_path):
    from distributed import LocalCluster
    from distributed.security import Security

    cert, key = _self_signed(tmp_path)
    server = Security(tls_ca_file=str(cert), tls_scheduler_cert=str(cert), tls_scheduler_key=str(key),
                      tls_worker_cert=str(cert), tls_worker_key=str(key), tls_client_cert=str(cert),
                      tls_client_key=str(key), require_encryption=True)
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, protocol="tls://", security=server,
                      dashboard_address=None) as cluster:
        assert cluster.scheduler_address.startswith("tls://")
        outcomes = parallel_map(math.sqrt, [4.0, 9.0], scheduler=cluster.scheduler_address,
                                security=tls_security(cert, cert, key))
    assert [o.value for o in outcomes] == [2.0, 3.0]


def _invoke(args):
    return CliRunner().invoke(app, args)


@pytest.mark.parametrize("command", [["study", "sweep", "plla"], ["study", "rve-size", "plla"],
                                     ["fit", "curve.csv"]])
def test_scheduler_options_of_the_commands_checked_before_any_work(tmp_path, command):
    out = tmp_path / "out"
    pem = tmp_path / "key.pem"
    pem.write_text(SECRET)
    cases = [
        (["--scheduler", "node-7:8786"], "scheduler"),
        (["--scheduler", "tls://node-7:8786"], "tls-ca-file"),
        (["--scheduler", "tls://node-7:8786", "--tls-ca-file", str(tmp_path / "no-ca.pem"), "--tls-cert", str(pem)],
         "no-ca.pem"),
        (["--scheduler", "tcp://node-7:8786", "--tls-ca-file", str(pem), "--tls-cert", str(pem)], "security"),
        (["--tls-key", str(pem)], "tls_ca_file"),
    ]
    for options, expected in cases:
        result = _invoke([*command, *options, "-o", str(out), "-q"])
        assert result.exit_code == 2, (options, result.output)
        assert expected in result.output and SECRET not in result.output, (options, result.output)
        assert not out.exists()


@pytest.mark.parametrize("command, target", [(["study", "sweep", "plla"], "espin.studies.sweeps.sweep"),
                                             (["fit", "curve.csv"], "espin.analysis.calibration.fit")])
def test_tls_files_reach_the_task_pool(tmp_path, monkeypatch, command, target):
    ca, cert, key = (tmp_path / name for name in ("ca.pem", "cert.pem", "key.pem"))
    for path in (ca, cert, key):
        path.write_text("placeholder")
    seen = {}

    def stop(*args, **kwargs):
        seen.update(kwargs)
        raise ConfigError("stopped here")

    monkeypatch.setattr(target, stop)
    result = _invoke([*command, "--scheduler", "tls://node-7:8786", "--tls-ca-file", str(ca), "--tls-cert",
                      str(cert), "--tls-key", str(key), "-o", str(tmp_path / "out"), "-q"])
    assert result.exit_code == 2 and "stopped here" in result.output, result.output
    security = seen["security"]
    assert (security.tls_ca_file, security.tls_client_cert, security.tls_client_key) == (str(ca), str(cert), str(key))
    assert security.require_encryption and seen["scheduler"] == "tls://node-7:8786"


def test_an_unreachable_scheduler_is_a_clear_error(monkeypatch):
    """Dask waits for its connect timeout (30 s by default; 1 s here), then: a ConfigError."""
    import dask

    from espin.core.errors import ConfigError

    with dask.config.set({"distributed.comm.timeouts.connect": "1s"}):
        with TaskPool(scheduler="tcp://127.0.0.1:9") as pool:
            with pytest.raises(ConfigError, match="tcp://127.0.0.1:9: cannot connect"):
                list(pool.map(abs, [1]))
