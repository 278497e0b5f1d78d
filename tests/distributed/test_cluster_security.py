"""A render-series cluster only its owner can reach (issue 29): another local process can neither
run code on the scheduler nor on a worker (TLS with keys made for the run), the only ports open
are the Dask comm ports that require those keys (no HTTP: no dashboard, no health or metrics
pages), and the workers end when the process that made the cluster dies."""
import json
import os
import signal
import socket
import ssl
import subprocess
import sys
import textwrap
import time

import pytest

distributed = pytest.importorskip("distributed")
pytest.importorskip("cryptography")
psutil = pytest.importorskip("psutil")

from hovr_blender.distributed import series  # noqa: E402

pytestmark = pytest.mark.slow
REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _listening(pids):
    """(pid, port) of every TCP socket in LISTEN state of the processes `pids`."""
    out = []
    for pid in pids:
        for conn in psutil.Process(pid).net_connections(kind="inet"):
            if conn.status == psutil.CONN_LISTEN:
                out.append((pid, conn.laddr.port))
    return out


def _tree():
    me = psutil.Process()
    return [me.pid] + [p.pid for p in me.children(recursive=True)]


@pytest.fixture(scope="module")
def cluster():
    cluster = series.local_cluster(2, "cpu")
    client = series.cluster_client(cluster)
    try:
        yield cluster, client
    finally:
        client.close()
        cluster.close()


def _port(address):
    return int(address.rsplit(":", 1)[1])


def test_only_the_runs_comm_ports_listen(cluster):
    cluster, client = cluster
    info = client.scheduler_info()
    assert cluster.scheduler_address.startswith("tls://127.0.0.1:")
    comm = {_port(cluster.scheduler_address)}
    for addr, w in info["workers"].items():
        comm.add(_port(addr))
        if w.get("nanny"):
            comm.add(_port(w["nanny"]))
    listening = _listening(_tree())
    assert {port for _, port in listening} == comm, (listening, comm)
    for port in comm:  # each one wants TLS with the run's certificate
        with socket.create_connection(("127.0.0.1", port), timeout=5) as raw:
            raw.sendall(b"GET / HTTP/1.0\r\n\r\n")
            raw.settimeout(5)
            try:
                answer = raw.recv(100)
            except (ConnectionResetError, socket.timeout):
                answer = b""
            assert not answer.startswith(b"HTTP"), port
        ctx = ssl.create_default_context()
        ctx.check_hostname = False
        ctx.verify_mode = ssl.CERT_NONE
        with pytest.raises((ssl.SSLError, ConnectionResetError, BrokenPipeError, socket.timeout, OSError)):
            with socket.create_connection(("127.0.0.1", port), timeout=5) as raw:
                with ctx.wrap_socket(raw) as tls:  # no client certificate
                    tls.sendall(b"x" * 64)
                    tls.settimeout(5)
                    if not tls.recv(1):
                        raise ConnectionResetError("closed")


ATTACKER = textwrap.dedent("""
    import asyncio, sys
    from distributed import Client
    from distributed.comm import connect
    from distributed.security import Security
    marker, scheduler, workers = sys.argv[1], sys.argv[2], sys.argv[3:]

    def payload():
        open(marker, "w").write("ran")

    for address, security in ((scheduler, None), (scheduler.replace("tls://", "tcp://"), None),
                              (scheduler, Security(require_encryption=True))):
        try:
            with Client(address, timeout=4, security=security) as c:
                c.run(payload)
                c.run_on_scheduler(payload)
            print("CONNECTED", address)
        except BaseException as exc:
            print("refused", address, type(exc).__name__)

    async def worker(address):
        try:
            comm = await asyncio.wait_for(connect(address, timeout=4), 6)
            await comm.write({"op": "run", "function": b"", "args": b"", "kwargs": b"", "reply": True})
            print("CONNECTED", address, await asyncio.wait_for(comm.read(), 6))
        except BaseException as exc:
            print("refused", address, type(exc).__name__)

    for address in workers:
        asyncio.run(worker(address))
""")


def test_another_process_cannot_run_code(cluster, tmp_path):
    cluster, client = cluster
    marker = tmp_path / "ran"
    workers = list(client.scheduler_info()["workers"])
    proc = subprocess.run([sys.executable, "-c", ATTACKER, str(marker), cluster.scheduler_address, *workers],
                          capture_output=True, text=True, timeout=120, env=dict(os.environ, PYTHONPATH=REPO))
    assert "CONNECTED" not in proc.stdout, proc.stdout + proc.stderr
    assert proc.stdout.count("refused") == 3 + len(workers), proc.stdout + proc.stderr
    assert not marker.exists()
    assert client.run(os.getpid)  # its owner still can


OWNER = textwrap.dedent("""
    import os, sys, time
    from hovr_blender.distributed import series
    cluster = series.local_cluster(1, "cpu")
    client = series.cluster_client(cluster)
    print(" ".join(str(p) for p in client.run(os.getpid).values()), flush=True)
    time.sleep(600)
""")


def test_workers_end_with_the_process_that_made_the_cluster():
    proc = subprocess.Popen([sys.executable, "-c", OWNER], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                            text=True, env=dict(os.environ, PYTHONPATH=REPO))
    try:
        pids = [int(p) for p in proc.stdout.readline().split()]
        assert pids and all(psutil.pid_exists(p) for p in pids)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and any(_alive(p) for p in pids):
            time.sleep(0.2)
        assert not any(_alive(p) for p in pids)
    finally:
        if proc.poll() is None:
            proc.kill()


def _alive(pid):
    try:
        return psutil.Process(pid).status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False


def test_scheduler_option_connects_with_the_users_tls_files(cluster, tmp_path):
    """--scheduler with --tls-ca-file/--tls-cert/--tls-key (series.remote_client): the cluster's CA
    and a certificate it signed connect; half the files, or a plain address, are refused."""
    cluster, _ = cluster
    files = {}
    for name, pem in (("ca", cluster.security.tls_ca_file), ("cert", cluster.security.tls_client_cert),
                      ("key", cluster.security.tls_client_key)):
        files[name] = tmp_path / f"{name}.pem"
        files[name].write_text(pem)
        os.chmod(files[name], 0o600)
    with series.remote_client(cluster.scheduler_address, str(files["ca"]), str(files["cert"]),
                              str(files["key"])) as client:
        assert client.run(os.getpid)
    with pytest.raises(ValueError, match="go together"):
        series.remote_client(cluster.scheduler_address, str(files["ca"]))
    with pytest.raises(RuntimeError, match="encryption required"):  # a plain tcp address is refused
        series.remote_client(cluster.scheduler_address.replace("tls://", "tcp://"), str(files["ca"]),
                             str(files["cert"]), str(files["key"]))


def _answers_http(port) -> bool:
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=2) as raw:
            raw.sendall(b"GET /health HTTP/1.0\r\n\r\n")
            raw.settimeout(2)
            return raw.recv(16).startswith(b"HTTP")
    except OSError:
        return False


def test_no_port_answers_http_during_a_whole_run(tmp_path):
    """`hovr render-series` on 2 workers, its process tree's listening sockets sampled from start to
    end (every ~20 ms): the scheduler's, the nannies' and the workers' TLS ports only, 5 in all, and
    each new one asked for HTTP at once. Dask's HTTP servers used to answer for ~5 s (scheduler)
    and ~1 s (worker) before they were closed; now they never start."""
    view = {"data": {"builtin": "sphere"}, "image": {"width": 16, "height": 12},
            "camera": {"eye": [0, 0, 5], "target": [0, 0, 0], "up": [0, 1, 0], "fov_y_deg": 40},
            "transfer_function": {"color": [[0, 1, 1, 1], [1, 1, 0, 0]], "density": [[0, 1], [1, 5]]},
            "background": [0, 0, 0]}
    (tmp_path / "view.json").write_text(json.dumps(view))
    (tmp_path / "out").mkdir()
    proc = subprocess.Popen([sys.executable, "-m", "hovr_blender.cli", "render-series", str(tmp_path / "view.json"),
                             "-o", str(tmp_path / "out" / "f_####.npy"), "--frames", "1-6", "--workers", "2",
                             "--device", "cpu"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            env=dict(os.environ, PYTHONPATH=REPO))
    seen, http, samples = set(), [], 0
    root = psutil.Process(proc.pid)
    while proc.poll() is None:
        try:
            tree = [root] + root.children(recursive=True)
        except psutil.NoSuchProcess:
            break
        for p in tree:
            try:
                ports = {c.laddr.port for c in p.net_connections(kind="inet") if c.status == psutil.CONN_LISTEN}
            except (psutil.NoSuchProcess, psutil.AccessDenied):
                continue
            for port in ports - seen:
                seen.add(port)
                if _answers_http(port):
                    http.append(port)
        samples += 1
        time.sleep(0.02)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err.decode()[-2000:]
    assert len(list((tmp_path / "out").glob("f_*.npy"))) == 6
    assert samples > 20 and not http, (samples, seen, http)
    assert len(seen) == 5, seen  # scheduler, 2 nannies, 2 workers: TLS all


KEEPS_ENVIRONMENT = textwrap.dedent("""
    import json, os
    from hovr_blender.distributed import series
    before = dict(os.environ)
    cluster = series.local_cluster(1, "cpu")
    client = series.cluster_client(cluster)
    workers = list(client.run(lambda: os.environ.get("OMP_NUM_THREADS")).values())
    changed = sorted(k for k in set(before) | set(os.environ) if before.get(k) != os.environ.get(k))
    client.close(); cluster.close()
    print(json.dumps({"changed": changed, "workers": workers}))
""")


def test_a_local_cluster_leaves_its_owners_environment_as_it_was():
    """Dask's nannies set their workers' pre-spawn variables (OMP_NUM_THREADS=1, MKL_..., OPENBLAS_...,
    MALLOC_TRIM_THRESHOLD_, PYTHONHASHSEED) in the process that starts them, for good: processes it
    started later (All CPU Cores' devices) ran BLAS on one thread against its several, and an image
    split over devices differed from one device's by 1e-5 (adaptive panels on host data rounded
    otherwise). The workers still get them; the owner's environment is as it was."""
    env = {k: v for k, v in os.environ.items()
           if k not in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MALLOC_TRIM_THRESHOLD_",
                        "PYTHONHASHSEED")}
    proc = subprocess.run([sys.executable, "-c", KEEPS_ENVIRONMENT], capture_output=True, text=True, timeout=180,
                          env=dict(env, PYTHONPATH=REPO))
    assert proc.returncode == 0, proc.stderr[-3000:]
    report = json.loads(proc.stdout.strip().splitlines()[-1])
    assert report == {"changed": [], "workers": ["1"]}
