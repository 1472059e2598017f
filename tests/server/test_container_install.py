"""The Dockerfile's install steps, replayed in a fresh virtual environment (no container engine needed): build
the wheels as its build stage does and install them as it does into the venv the final stage copies (the client and
the server, no lab), start `graspd serve` from that venv, pass the image's HEALTHCHECK command, and stop gracefully
on SIGTERM.  tests/server/test_container_image.py builds and runs the real image (podman, root); this one runs on
any machine.

By default third-party dependencies come from the project venv (a .pth file; nothing is downloaded);
GRASPD_FULL_INSTALL=1 resolves them from the package index exactly as `docker build` would."""

from __future__ import annotations

import json
import os
import re
import shlex
import signal
import site
import subprocess
import time
import venv
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def dockerfile_steps() -> tuple[list[list[str]], list[str], dict[str, str]]:
    """What the build stage makes wheels of and what the final stage installs from them (the arguments after
    the wheel folder of `pip wheel --wheel-dir W ...` and of `pip install --no-index --find-links W ...`), the
    HEALTHCHECK exec form and the ENV values of the Dockerfile."""
    text = (ROOT / "Dockerfile").read_text().replace("\\\n", " ")
    wheels = re.findall(r"^RUN pip wheel --wheel-dir \S+ (.+)$", text, re.M)
    installs = re.findall(r"pip install --no-index --find-links \S+ (.+)$", text, re.M)
    pip = [shlex.split(m) for m in [*wheels, *installs]]
    health = json.loads(re.search(r"HEALTHCHECK .*?CMD (\[.+\])", text).group(1))  # type: ignore[union-attr]
    env: dict[str, str] = {}
    for block in re.findall(r"^ENV (.+)$", text, re.M):
        for key, value in re.findall(r"(\w+)=('[^']*'|\S+)", block):
            env[key] = value.strip("'")
    return pip, health, env


@pytest.mark.slow
def test_dockerfile_install_steps_in_fresh_venv(tmp_path: Path) -> None:
    pip_steps, health, docker_env = dockerfile_steps()
    # wheels of the client and the server with its PostgreSQL extra; installed by name, the lab never
    assert pip_steps == [["./client", ".[postgres]"], ["graspd-client", "graspd[postgres]"]], pip_steps
    env_dir = tmp_path / "venv"
    venv.EnvBuilder(with_pip=True).create(env_dir)
    py = env_dir / "bin" / "python"
    full = os.environ.get("GRASPD_FULL_INSTALL") == "1"
    if not full:
        purelib = subprocess.check_output([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                                          text=True).strip()
        Path(purelib, "project-deps.pth").write_text("\n".join(site.getsitepackages()) + "\n")
        # build with the project's setuptools (>= 68, has bdist_wheel), not the venv's bundled older one
        subprocess.run([str(py), "-m", "pip", "uninstall", "-q", "-y", "setuptools"], check=True)
    build = tmp_path / "context"  # a copy of the build context, so the checkout gets no build/ folders
    parts = " ".join(p for p in ("client", "service", "pyproject.toml", "README.md", "models") if (ROOT / p).exists())
    subprocess.run(f"tar -C {ROOT} --exclude=__pycache__ -cf - {parts} | (mkdir -p {build} && tar -C {build} -xf -)",
                   shell=True, check=True)
    wheels = tmp_path / "wheels"
    extra = [] if full else ["--no-deps", "--no-build-isolation", "--no-index"]
    subprocess.run([str(py), "-m", "pip", "wheel", "-q", "--wheel-dir", str(wheels), *extra, *pip_steps[0]],
                   cwd=build, check=True, timeout=1800)
    wheel = next(wheels.glob("graspd-*.whl"))  # the server's own requirements: no open3d, torch or pybullet
    with zipfile.ZipFile(wheel) as archive:
        meta = archive.read(next(n for n in archive.namelist() if n.endswith(".dist-info/METADATA"))).decode()
    required = [line.split(":", 1)[1].strip().lower() for line in meta.splitlines()
                if line.startswith("Requires-Dist:") and "extra ==" not in line]
    assert required and not [r for r in required if r.startswith(("open3d", "torch", "pybullet"))], required
    # --ignore-installed: the .pth shows pip the project's editable graspd, which it would keep instead
    local = [] if full else ["--no-deps", "--ignore-installed"]
    subprocess.run([str(py), "-m", "pip", "install", "-q", "--no-index", "--find-links", str(wheels), *local,
                    *pip_steps[1]], cwd=build, check=True, timeout=1800)
    port = 18000 + os.getpid() % 1000
    env = {**docker_env, "GRASPD_MODELS_DIR": str(build / "models"), "GRASPD_HOST": "127.0.0.1",
           "GRASPD_PORT": str(port), "GRASPD_ZENOH_ENABLED": "false", "PATH": f"{env_dir / 'bin'}:/usr/bin:/bin",
           "HOME": str(tmp_path)}
    server = subprocess.Popen([str(env_dir / "bin" / "graspd"), "serve"], env=env, cwd=tmp_path,
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        check = [str(py) if health[0] == "python" else health[0], *health[1:]]
        check = [c.replace("8000", str(port)) for c in check]
        deadline = time.monotonic() + 120
        while subprocess.run(check, env=env, capture_output=True).returncode != 0:
            assert server.poll() is None, server.stdout.read() if server.stdout else ""
            assert time.monotonic() < deadline, "HEALTHCHECK never passed"
            time.sleep(0.5)
        imported = subprocess.check_output([str(py), "-c", "import graspd, graspd_client, psycopg; "
                                            "print(graspd.__file__)"], text=True, cwd=tmp_path)  # postgres extra
        assert str(env_dir) in imported  # the installed copy, not the checkout
        lab = subprocess.run([str(py), "-c", "import graspd_lab"], capture_output=True, cwd=tmp_path)
        assert lab.returncode != 0  # the image holds no lab
        if full:  # resolved from the index as `docker build` does: open3d is not among the image's packages
            o3d = subprocess.run([str(py), "-c", "import open3d"], capture_output=True, cwd=tmp_path)
            assert o3d.returncode != 0
    finally:
        server.send_signal(signal.SIGTERM)
        out, _ = server.communicate(timeout=60)
    assert server.returncode in (0, -signal.SIGTERM), out  # uvicorn re-raises SIGTERM after a clean shutdown
    assert '"msg": "graspd shutting down' in out and "Application shutdown complete" in out


def test_dockerfile_final_stage_is_slim_non_root_and_checks_readiness() -> None:
    """Fast checks of the Dockerfile as text: two stages from debian:bookworm-slim; the final one installs only
    Python and OpenMP from Debian (open3d's GL/EGL/X11 and libusb libraries went with open3d) and copies the build
    stage's venv (it runs no pip: no installer, no cache), runs as a non-root user and its HEALTHCHECK asks /readyz
    on the port GRASPD_PORT names."""
    text = (ROOT / "Dockerfile").read_text().replace("\\\n", " ")
    assert re.findall(r"^FROM (\S+)", text, re.M) == ["debian:bookworm-slim", "debian:bookworm-slim"]
    final = text[text.rindex("\nFROM "):]
    apt = re.findall(r"apt-get install ([^&\n]+)", final)
    assert len(apt) == 1
    assert [w for w in apt[0].split() if not w.startswith("-")] == ["python3", "libgomp1"]
    assert "COPY --from=build /opt/venv /opt/venv" in final
    assert not re.search(r"\bpip\b", "\n".join(re.findall(r"^RUN .*$", final, re.M)))
    user = re.findall(r"^USER (\S+)", text, re.M)
    assert user and user[-1] not in ("root", "0")
    _, health, _ = dockerfile_steps()
    assert any("/readyz" in part and "GRASPD_PORT" in part for part in health)
