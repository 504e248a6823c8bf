"""docker-compose.yml without a Docker daemon: every service's command is a real invocation of a
program the image installs, parsed by that program's own argument parser, its files exist, and
the services' ports meet (the stub sends vehicle i to the companion's 14540 + i, and its GCS link
to where MAVProxy listens). The speed factor is a setting with a default, the run ends with the
companion, and the image has no GUI stack and stays under 500 MB (estimated from the installed
packages' files: there is no Docker daemon here)."""

from __future__ import annotations

import importlib.metadata as metadata
import importlib.util
import os
import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path
from urllib.parse import urlparse

import pytest
import yaml
from packaging.requirements import Requirement

from companion.cli import build_parser as companion_parser
from uav_model.mission import load_mission
from sim_bridge.cli import build_parser as sim_parser
from sim_bridge.cli import options_from_args

ROOT = Path(__file__).resolve().parents[1]
COMPOSE = yaml.safe_load((ROOT / "docker-compose.yml").read_text())
SERVICES = COMPOSE["services"]
DOCKERFILE = (ROOT / "Dockerfile").read_text()
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())
BIN = Path(sys.executable).parent


COMPOSE_TEXT = (ROOT / "docker-compose.yml").read_text()
SETTING = re.compile(r"\$\{(\w+):-([^}]*)\}")


def _command(service: str) -> list[str]:
    """The service's command as compose runs it by default: ``${VAR:-default}`` is the default."""
    command = SERVICES[service]["command"]
    assert isinstance(command, list) and all(isinstance(a, str) for a in command), \
        f"{service}: command must be an exec-form list of strings"
    return [SETTING.sub(lambda m: m.group(2), a) for a in command]


def _in_image(path: str) -> Path:
    """A path relative to the image's WORKDIR, found in the checkout the Dockerfile copies from."""
    workdir = re.search(r"^WORKDIR\s+(\S+)", DOCKERFILE, re.MULTILINE).group(1)
    copied = {dst.rstrip("/").removeprefix("./"): src for src, dst in
              re.findall(r"^COPY\s+(\S+)\s+(\S+)\s*$", DOCKERFILE, re.MULTILINE)}
    rel = Path(path).relative_to(workdir) if path.startswith("/") else Path(path)
    assert rel.parts[0] in copied, f"{path}: the Dockerfile does not COPY {rel.parts[0]} into {workdir}"
    return ROOT / copied[rel.parts[0]] / Path(*rel.parts[1:])


def _sim_args():
    cmd = _command("sim")
    assert cmd[0] == "sim-bridge"
    args = sim_parser().parse_args(cmd[1:])
    options_from_args(args)  # the stub's own validation of the options
    return args


def _companion_args():
    cmd = _command("companion")
    assert cmd[0] == "companion"
    return companion_parser().parse_args(cmd[1:])


def test_every_service_runs_a_program_the_image_installs():
    scripts = set(PYPROJECT["project"]["scripts"])
    assert {_command(s)[0] for s in ("sim", "companion")} <= scripts
    assert _command("mavproxy")[0] == "mavproxy.py"  # from MAVProxy, the gcs extra
    assert any("MAVProxy" in req for req in PYPROJECT["project"]["optional-dependencies"]["gcs"])
    assert re.search(r"pip install --no-cache-dir \.( |$)", DOCKERFILE, re.MULTILINE), "the image installs the project"
    for service in SERVICES.values():
        assert service.get("build") == "." and service.get("image") == SERVICES["sim"]["image"]


def _dockerfile_installs() -> set[str]:
    names = set()
    for line in re.findall(r"pip install ([^\n\\&]+)", DOCKERFILE):
        names |= {Requirement(w.strip('"')).name.lower() for w in line.split() if not w.startswith("-") and w != "."}
    return names


# The image's MAVProxy is read from this environment's install of it (an extra, as in .ci/run).
needs_mavproxy = pytest.mark.skipif(
    importlib.util.find_spec("MAVProxy") is None,
    reason="needs MAVProxy (the gcs extra, headless): pip install --no-deps 'MAVProxy>=1.8.70' pyserial pynmeagps defusedxml")


@needs_mavproxy
def test_the_image_has_mavproxy_without_its_gui_stack():
    assert re.search(r'pip install --no-cache-dir --no-deps "MAVProxy', DOCKERFILE)
    installed = _dockerfile_installs()
    everywhere = {Requirement(r).name.lower() for r in metadata.requires("MAVProxy") if ";" not in r}
    assert everywhere <= installed, f"MAVProxy needs {sorted(everywhere - installed)}"
    gui = {"vtk", "opencv-python", "quantized-mesh-tile", "wxpython", "pygame"}
    assert not gui & installed
    assert "mavproxy_cesium" in DOCKERFILE  # the browser map's 114 MB of JavaScript


BASE_IMAGE_MB = 130.0  # python:3.11-slim unpacked (Debian bookworm + CPython): ~45 MB compressed


def _installed_mb(names: list[str], skip: str) -> float:
    """The on-disk size of these distributions and their dependency closure, as pip installs it
    here (files listed in each RECORD, byte-compiled .pyc included), without paths containing ``skip``."""
    seen: dict[str, metadata.Distribution] = {}
    todo = [Requirement(n) for n in names]
    while todo:
        req = todo.pop()
        key = req.name.lower().replace("_", "-")
        if key in seen or (req.marker is not None and not req.marker.evaluate({"extra": ""})):
            continue
        seen[key] = dist = metadata.distribution(req.name)
        if key != "mavproxy":  # installed --no-deps: its requirements are listed explicitly
            todo += [Requirement(r) for r in dist.requires or []]
    total = 0
    for dist in seen.values():
        for f in dist.files or []:
            if skip not in str(f) and os.path.exists(path := f.locate()):
                total += os.path.getsize(path)
    return total / 1e6


@needs_mavproxy
def test_the_image_is_under_500_mb_by_its_installed_packages():
    project = [r for r in metadata.requires("astar-bdwa") if "extra ==" not in r]
    extra = sorted(_dockerfile_installs() - {"mavproxy"}) + ["MAVProxy"]
    packages_mb = _installed_mb(project + extra, skip="mavproxy_cesium")
    estimate = BASE_IMAGE_MB + packages_mb
    print(f"image estimate: {BASE_IMAGE_MB:.0f} MB base + {packages_mb:.0f} MB packages = {estimate:.0f} MB")
    assert estimate <= 500.0


def test_the_speed_factor_is_a_setting_and_the_run_ends_with_the_companion():
    sim = _command("sim")
    (setting,) = [m for a in SERVICES["sim"]["command"] for m in SETTING.finditer(a)]
    assert setting.group(1) == "SPEEDUP" and float(setting.group(2)) > 1.0
    assert sim[sim.index("--speedup") + 1] == setting.group(2)
    # There is no compose-file key for it: the documented command line ends the run.
    assert "docker compose up --exit-code-from companion" in COMPOSE_TEXT
    for doc in ("README.md", "docs/docker.md"):
        assert "docker compose up --exit-code-from companion" in (ROOT / doc).read_text(), doc


def test_the_stub_command_parses_and_its_mission_exists():
    args = _sim_args()
    mission = load_mission(_in_image(str(args.mission)))
    assert args.host == "companion" and args.bind == "0.0.0.0"  # reachable across the compose network
    assert len(mission.vehicles) == 2


def test_the_companion_command_parses_and_listens_where_the_stub_sends():
    sim, comp = _sim_args(), _companion_args()
    assert comp.func.__name__ == "cmd_run"
    assert _in_image(str(comp.mission)) == _in_image(str(sim.mission))
    mission = load_mission(_in_image(str(comp.mission)))
    listens = {name: urlparse(url) for name, url in comp.connect}
    assert set(listens) == {v.name for v in mission.vehicles}
    for v in mission.vehicles:
        url = listens[v.name]
        assert url.scheme == "udpin" and url.hostname == "0.0.0.0", url
        assert url.port == sim.api_port_base + v.index  # PX4 SITL convention: 14540 + i
    assert comp.shared_clock  # one sim-bridge clock for both vehicles and the obstacles
    # Both write into the mounted ./out.
    assert Path(comp.out) == Path(sim.tlog) == Path("/out")
    for name in ("sim", "companion"):
        assert "./out:/out" in SERVICES[name]["volumes"]


def test_the_gcs_service_listens_where_the_stub_sends_its_gcs_link():
    sim = _sim_args()
    gcs = SERVICES["mavproxy"]
    assert gcs["profiles"] == ["gcs"]
    # It shares the companion's network namespace: the stub's --host reaches it.
    assert gcs["network_mode"] == f"service:{sim.host}"
    master = next(a.split("=", 1)[1] for a in _command("mavproxy") if a.startswith("--master="))
    scheme, host, port = master.split(":")
    assert scheme == "udpin" and host == "0.0.0.0" and int(port) == sim.gcs_port and not sim.no_gcs


@pytest.mark.parametrize("service", ["sim", "companion", pytest.param("mavproxy", marks=needs_mavproxy)])
def test_the_command_runs_natively(service):
    cmd = _command(service)
    exe = shutil.which(cmd[0], path=str(BIN)) or shutil.which(cmd[0])
    assert exe, f"{cmd[0]} is not installed"
    if service == "companion":
        help_cmd = [exe, cmd[1], "--help"]  # the subcommand's own help
    else:
        help_cmd = [exe, "--help"]
    result = subprocess.run(help_cmd, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr[-2000:]
    # MAVProxy parses with optparse and has no parser to borrow: its help must list each option.
    for arg in cmd[1:]:
        if arg.startswith("--"):
            assert arg.split("=", 1)[0] in result.stdout, f"{service}: {arg} is not a {cmd[0]} option"
