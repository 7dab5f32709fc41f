"""Build the project's ROS 2 interface packages (runtime/ros/interfaces/*) into the venv.

Run with the venv's python: ``objective build-interfaces`` (or ``python -m
runtime.build_interfaces``; ``make setup`` does it). The sources ship with the package, so an
installed wheel builds them as a checkout does; it needs cmake, a C compiler and the build-time
wheels of the ``ros-build`` extra (``pip install 'objective-runtime[ros-build]'``). Stdlib only,
idempotent, and quick when nothing changed.

Why plain cmake into the venv prefix: the ROS 2 Jazzy wheels put their libraries in
``<venv>/lib`` and a start-up hook adds that directory to the library path, so packages
installed there are importable from a fresh shell with nothing sourced (colcon would install to
./install and need environment scripts).

Two steps:
1. Repair the CMake export files shipped by the message wheels. They name the include
   directories of the machine the wheels were built on (``/opt/python/cp311-cp311/...``), and
   CMake refuses imported targets whose include directories do not exist. We point them at this
   interpreter's headers and this venv's numpy headers.
2. For each package, in dependency order (leaving out a package a sourced ROS install already
   has, found in ``AMENT_PREFIX_PATH``, unless it is named): configure, build and install with cmake (build
   directory ``<build-dir>/<pkg>``, by default ``<venv>/build/objective-interfaces``), unless its sources are unchanged since the last
   successful build (hash stamp) and its Python types still load (the venv may have been
   recreated since).
"""
from __future__ import annotations

import argparse
import hashlib
import os
import re
import shutil
import subprocess
import sys
import sysconfig
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

from .command import Command

INTERFACES_DIR = Path(__file__).resolve().parent / "ros" / "interfaces"
STAMP_NAME = "source-hash.stamp"
MAX_JOBS = 2  # the machines are small and shared; never more than two compile jobs
TAIL_LINES = 60

# The wheel-build machine's paths baked into the wheels' CMake exports.
_WHEEL_PYTHON_INCLUDE = re.compile(r"/opt/python/cp3\d+-cp3\d+/include/python3\.\d+")
_WHEEL_NUMPY_INCLUDE = re.compile(r"/opt/python/cp3\d+-cp3\d+/lib/python3\.\d+/site-packages/numpy/(?:_core|core)/include")


class BuildError(RuntimeError):
    """A package failed to build; the message names it and carries the tail of the output."""


@dataclass
class Package:
    name: str
    path: Path
    depends: set[str] = field(default_factory=set)

    def interfaces(self) -> list[tuple[str, str]]:
        """(kind, TypeName) for every .msg/.srv/.action, e.g. ("srv", "GetActionChunk")."""
        found = []
        for kind, ext in (("msg", ".msg"), ("srv", ".srv"), ("action", ".action")):
            for f in sorted((self.path / kind).glob(f"*{ext}")):
                found.append((kind, f.stem))
        return found


# --------------------------------------------------------------------------------------------
# Pure helpers
# --------------------------------------------------------------------------------------------
def rewrite_wheel_paths(text: str, python_include: str, numpy_include: str) -> str:
    """Replace the wheel-build machine's include paths with this machine's (numpy first: it is
    the longer match and shares the prefix)."""
    text = _WHEEL_NUMPY_INCLUDE.sub(lambda _: numpy_include, text)
    return _WHEEL_PYTHON_INCLUDE.sub(lambda _: python_include, text)


def read_package(path: Path) -> Package:
    manifest = path / "package.xml"
    try:
        root = ET.parse(manifest).getroot()
    except ET.ParseError as exc:
        raise BuildError(f"{manifest}: not valid XML: {exc}") from None
    name = (root.findtext("name") or "").strip()
    if name != path.name:
        raise BuildError(f"{manifest}: <name> is '{name}' but the directory is '{path.name}'")
    deps = {
        (el.text or "").strip()
        for tag in ("depend", "build_depend")
        for el in root.findall(tag)
    }
    return Package(name, path, deps)


def dependency_order(packages: list[Package]) -> list[Package]:
    """Topological order over the project's own packages (external dependencies are ignored)."""
    by_name = {p.name: p for p in packages}
    ordered: list[Package] = []
    state: dict[str, str] = {}

    def visit(pkg: Package, chain: list[str]) -> None:
        if state.get(pkg.name) == "done":
            return
        if state.get(pkg.name) == "visiting":
            raise BuildError("dependency cycle between interface packages: " + " -> ".join(chain + [pkg.name]))
        state[pkg.name] = "visiting"
        for dep in sorted(pkg.depends):
            if dep in by_name:
                visit(by_name[dep], chain + [pkg.name])
        state[pkg.name] = "done"
        ordered.append(pkg)

    for pkg in sorted(packages, key=lambda p: p.name):
        visit(pkg, [])
    return ordered


def source_hash(pkg: Package, extra: str) -> str:
    """Hash of every file in the package (path and content) plus ``extra`` (toolchain facts)."""
    digest = hashlib.sha256(extra.encode())
    for f in sorted(p for p in pkg.path.rglob("*") if p.is_file() and "__pycache__" not in p.parts):
        digest.update(str(f.relative_to(pkg.path)).encode() + b"\0")
        digest.update(f.read_bytes() + b"\0")
    return digest.hexdigest()


def tail(text: str, lines: int = TAIL_LINES) -> str:
    return "\n".join(text.rstrip().splitlines()[-lines:])


# --------------------------------------------------------------------------------------------
# Steps with I/O
# --------------------------------------------------------------------------------------------
def fix_cmake_exports(prefix: Path) -> int:
    """The CMake export files of the ROS wheels name the include directories of the machine the
    wheels were built on (``/opt/python/...``): point them at this venv's Python and numpy
    headers, or a package that links against them fails to configure. Returns how many files
    were rewritten."""
    import numpy  # the venv has it; needed only for its include path

    python_include = sysconfig.get_paths()["include"]
    numpy_include = numpy.get_include()
    changed = 0
    for f in (prefix / "share").rglob("*.cmake"):
        text = f.read_text(errors="surrogateescape")
        if "/opt/python/" not in text:
            continue
        new = rewrite_wheel_paths(text, python_include, numpy_include)
        if new != text:
            f.write_text(new, errors="surrogateescape")
            changed += 1
    return changed


def types_load(pkg: Package, env: dict[str, str]) -> bool:
    """Whether every generated Python type of ``pkg`` imports and instantiates (which loads its
    C type support), checked in a fresh interpreter so this process's import cache is no judge."""
    lines = []
    for kind, name in pkg.interfaces():
        lines.append(f"from {pkg.name}.{kind} import {name}")
        parts = {"msg": [""], "srv": [".Request", ".Response"], "action": [".Goal", ".Result", ".Feedback"]}[kind]
        lines.extend(f"{name}{part}()" for part in parts)
    if not lines:
        return True
    proc = subprocess.run([sys.executable, "-c", "\n".join(lines)], env=env, capture_output=True, text=True)
    return proc.returncode == 0


def run_step(pkg: Package, step: str, cmd: list[str], env: dict[str, str], log: Path) -> None:
    proc = subprocess.run(cmd, env=env, cwd=log.parent, capture_output=True, text=True)
    with log.open("a") as fh:
        fh.write(f"$ {' '.join(cmd)}\n{proc.stdout}{proc.stderr}\n")
    if proc.returncode != 0:
        raise BuildError(
            f"interface package '{pkg.name}': cmake {step} failed (exit {proc.returncode}); "
            f"full log: {log}\n--- last {TAIL_LINES} lines ---\n{tail(proc.stdout + proc.stderr)}"
        )


def build_package(pkg: Package, prefix: Path, env: dict[str, str], build_dir: Path) -> None:
    build = build_dir / pkg.name
    # A clean configure every time the sources change: cheap next to the compile, and immune to
    # stale caches after the venv was recreated.
    if build.exists():
        shutil.rmtree(build)
    build.mkdir(parents=True)
    log = build / "build.log"
    run_step(pkg, "configure", [
        "cmake", "-S", str(pkg.path), "-B", str(build),
        f"-DCMAKE_PREFIX_PATH={prefix}", f"-DCMAKE_INSTALL_PREFIX={prefix}",
        f"-DPython3_EXECUTABLE={sys.executable}", "-DBUILD_TESTING=OFF",
        "-DCMAKE_BUILD_TYPE=Release",
    ], env, log)
    run_step(pkg, "build", ["cmake", "--build", str(build), "--parallel", str(MAX_JOBS)], env, log)
    run_step(pkg, "install", ["cmake", "--install", str(build)], env, log)


def provided_elsewhere(name: str, prefix: Path, environ: dict[str, str]) -> Path | None:
    """The prefix of a sourced ROS (``AMENT_PREFIX_PATH``, other than this venv) that already has
    the package ``name`` in its ament index; building it here would hide that one."""
    for entry in environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        other = Path(entry) if entry else None
        if other is None or other.resolve() == prefix.resolve():
            continue
        if (other / "share" / "ament_index" / "resource_index" / "packages" / name).is_file():
            return other
    return None


def build_env(prefix: Path) -> dict[str, str]:
    env = dict(os.environ)
    env["PATH"] = f"{prefix / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    lib = str(prefix / "lib")
    if lib not in env.get("LD_LIBRARY_PATH", "").split(os.pathsep):
        env["LD_LIBRARY_PATH"] = os.pathsep.join(p for p in (lib, env.get("LD_LIBRARY_PATH", "")) if p)
    env["AMENT_PREFIX_PATH"] = str(prefix)
    env["CMAKE_PREFIX_PATH"] = str(prefix)
    env.setdefault("CMAKE_BUILD_PARALLEL_LEVEL", str(MAX_JOBS))
    env.setdefault("MAKEFLAGS", f"-j{MAX_JOBS}")
    return env


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--force", action="store_true", help="rebuild every package even if unchanged")
    parser.add_argument("--build-dir", type=Path, metavar="DIR",
                        help="cmake build directories and stamps (default: <venv>/build/objective-interfaces)")
    parser.add_argument("packages", nargs="*", help="only these packages (default: all)")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_arguments(parser)
    return build(parser.parse_args(argv))


def build(args: argparse.Namespace, registry: object = None) -> int:
    """Build what ``args`` asks for (the options of ``add_arguments``); the exit code."""
    if sys.prefix == sys.base_prefix:
        print(f"build_interfaces: run me with the venv's python (e.g. .venv/bin/python), not {sys.executable}",
              file=sys.stderr)
        return 2
    if shutil.which("cmake") is None:
        print("build_interfaces: cmake is not on PATH (apt-get install cmake)", file=sys.stderr)
        return 2
    prefix = Path(sys.prefix)
    build_dir = (args.build_dir or prefix / "build" / "objective-interfaces").resolve()

    try:
        fixed = fix_cmake_exports(prefix)
        if fixed:
            print(f"build_interfaces: repaired wheel include paths in {fixed} CMake export files")
        packages = dependency_order(
            [read_package(d) for d in sorted(INTERFACES_DIR.iterdir()) if (d / "package.xml").is_file()]
        )
        unknown = set(args.packages) - {p.name for p in packages}
        if unknown:
            raise BuildError(f"unknown interface package(s): {', '.join(sorted(unknown))}; "
                             f"have {', '.join(p.name for p in packages)}")
        env = build_env(prefix)
        # A new interpreter, venv location or build recipe (this file) also invalidates a build.
        toolchain = f"{sys.version}|{prefix}|{hashlib.sha256(Path(__file__).read_bytes()).hexdigest()}"
        for pkg in packages:
            if args.packages and pkg.name not in args.packages:
                continue
            elsewhere = provided_elsewhere(pkg.name, prefix, dict(os.environ))
            if elsewhere is not None and pkg.name not in args.packages:
                print(f"{pkg.name}: skipped, {elsewhere} has it (name it to build this copy, which would hide that one)",
                      flush=True)
                continue
            start = time.monotonic()
            digest = source_hash(pkg, toolchain)
            stamp = build_dir / pkg.name / STAMP_NAME
            if not args.force and stamp.is_file() and stamp.read_text().strip() == digest and types_load(pkg, env):
                print(f"{pkg.name}: up to date ({time.monotonic() - start:.1f} s)", flush=True)
                continue
            build_package(pkg, prefix, env, build_dir)
            if not types_load(pkg, env):
                raise BuildError(f"interface package '{pkg.name}': built and installed into {prefix}, "
                                 f"but its Python types do not load (try: {sys.executable} -c "
                                 f"'import {pkg.name}.{pkg.interfaces()[0][0]}')")
            stamp.write_text(digest + "\n")
            print(f"{pkg.name}: built in {time.monotonic() - start:.1f} s", flush=True)
    except BuildError as exc:
        print(f"build_interfaces: FAILED: {exc}", file=sys.stderr)
        return 1
    return 0


COMMAND = Command("build the ROS 2 interface packages shipped in runtime/ros/interfaces into this venv",
                  add_arguments, build, needs_registry=False)

if __name__ == "__main__":
    sys.exit(main())
