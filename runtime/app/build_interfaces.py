"""Build the project's ROS 2 interface packages (runtime/io/ros/interfaces/*) into the venv.

Run with the venv's python: ``objective build-interfaces`` (or ``python -m
runtime.app.build_interfaces``; ``make setup`` does it). The sources ship with the package, so an
installed wheel builds them as a checkout does; it needs cmake, a C compiler and the build-time
wheels of the ``ros-build`` extra (``pip install 'objective-runtime[ros-build]'``). Stdlib only,
idempotent, and quick when nothing changed.

Why plain cmake into the venv prefix: the ROS 2 Jazzy wheels put their libraries in
``<venv>/lib`` and a start-up hook adds that directory to the library path, so packages
installed there are importable from a fresh shell with nothing sourced (colcon would install to
./install and need environment scripts).

Steps:
1. Repair the CMake export files shipped by the message wheels. They name the include
   directories of the machine the wheels were built on (``/opt/python/cp311-cp311/...``), and
   CMake refuses imported targets whose include directories do not exist. We point them at this
   interpreter's headers and this venv's numpy headers.
2. For each package (leaving out a package a sourced ROS install already has, found in
   ``AMENT_PREFIX_PATH``, unless it is named): nothing when the venv holds the build of its
   current sources (``share/<pkg>/objective-interfaces.json`` names its key) and its Python
   types load; else install it from the machine's cache (``runtime.app.disk_cache``, kind
   ``interfaces``: one archive per package, keyed by its sources, the Python ABI, the installed
   ROS 2 wheels and this file, not by the venv, so every clone and venv on the machine reuses
   it); else configure, build and install it with cmake (build directory
   ``<build-dir>/<pkg>``, by default ``<venv>/build/objective-interfaces``) and store it there.
   Packages of one dependency level build side by side, at most ``MAX_JOBS`` compile jobs in all.

What is built is what rclpy uses: the C structs, the C type supports (Fast DDS's and the
introspection one) and the Python bindings; the C++ generators are left out (nothing in a venv
includes the C++ headers), as is optimisation (``-O0``, colcon's default build type), and each
library compiles as a few unity translation units: control_msgs takes 48 s of CPU instead of
the 210 s of a default ``rosidl_generate_interfaces`` build.
"""
from __future__ import annotations

import argparse
import hashlib
import io
import json
import os
import re
import shutil
import subprocess
import sys
import sysconfig
from typing import Any
import tarfile
import tempfile
import time
import xml.etree.ElementTree as ET
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path

from . import disk_cache
from .command import Command
from runtime.extras import INTERFACES_DIR

CACHE_KIND = "interfaces"
MARKER = "objective-interfaces.json"
"""In ``<prefix>/share/<pkg>/``: the key of the build installed there, the prefix it was
installed for, and its files (relative to the prefix), so the next version removes them."""
MAX_JOBS = 2  # the machines are small and shared; never more than two compile jobs
TAIL_LINES = 60

GENERATORS_CMAKE = r"""# Written by runtime/app/build_interfaces.py; CMake runs it at the package's project() call.
# 1. Only the generators rclpy uses: a find_package() hook drops every C++ generator's extension
#    (rosidl_generator_cpp, rosidl_typesupport_cpp, *_introspection_cpp, *_fastrtps_cpp) as soon
#    as the generators register theirs; the C ones and rosidl_generator_py stay.
macro(objective_python_generators_only method package_name)
  find_package(${package_name} ${ARGN} BYPASS_PROVIDER)
  if(DEFINED AMENT_EXTENSIONS_rosidl_generate_idl_interfaces)
    list(FILTER AMENT_EXTENSIONS_rosidl_generate_idl_interfaces EXCLUDE REGEX "_cpp:")
  endif()
endmacro()
cmake_language(SET_DEPENDENCY_PROVIDER objective_python_generators_only SUPPORTED_METHODS FIND_PACKAGE)

# 2. Every library compiles as unity translation units (headers parsed once per 8 sources),
#    except the type descriptions, whose file-local names repeat from file to file.
function(objective_unity_libraries)
  get_property(targets DIRECTORY "${CMAKE_SOURCE_DIR}" PROPERTY BUILDSYSTEM_TARGETS)
  foreach(target ${targets})
    get_property(type TARGET ${target} PROPERTY TYPE)
    if(type MATCHES "LIBRARY$")
      set_property(TARGET ${target} PROPERTY UNITY_BUILD ON)
      get_property(sources TARGET ${target} PROPERTY SOURCES)
      foreach(source ${sources})
        if(source MATCHES "__description[.]c$")
          set_property(SOURCE ${source} PROPERTY SKIP_UNITY_BUILD_INCLUSION ON)
        endif()
      endforeach()
    endif()
  endforeach()
endfunction()
cmake_language(DEFER DIRECTORY "${CMAKE_SOURCE_DIR}" CALL objective_unity_libraries)
"""
"""What ``CMAKE_PROJECT_TOP_LEVEL_INCLUDES`` runs in every package (CMake >= 3.24)."""
GENERATORS_CMAKE_SINCE = (3, 24)

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


def dependency_levels(packages: list[Package]) -> list[list[Package]]:
    """The packages of ``dependency_order`` in levels that can build side by side: a package's
    level is one past its deepest project dependency's; within a level, most interfaces first
    (the longest build starts first)."""
    level: dict[str, int] = {}
    for pkg in dependency_order(packages):
        level[pkg.name] = 1 + max((level[d] for d in pkg.depends if d in level), default=-1)
    levels: list[list[Package]] = [[] for _ in range(1 + max(level.values(), default=-1))]
    for pkg in packages:
        levels[level[pkg.name]].append(pkg)
    return [sorted(group, key=lambda p: (-len(p.interfaces()), p.name)) for group in levels]


def source_hash(pkg: Package, extra: str) -> str:
    """Hash of every file in the package (path and content) plus ``extra`` (toolchain facts)."""
    digest = hashlib.sha256(extra.encode())
    for f in sorted(p for p in pkg.path.rglob("*") if p.is_file() and "__pycache__" not in p.parts):
        digest.update(str(f.relative_to(pkg.path)).encode() + b"\0")
        digest.update(f.read_bytes() + b"\0")
    return digest.hexdigest()


def is_build_input(distribution: str) -> bool:
    """Whether an installed distribution shapes the built packages: the ROS 2 wheels (generators,
    type supports, the message packages ours include), empy (the generators' templates) and
    numpy (its headers)."""
    name = re.sub(r"[-_.]+", "-", distribution).lower()
    return name.startswith("ros-") or name in ("empy", "numpy")


def cmake_arguments(source: Path, build: Path, prefix: Path, generators_script: Path | None,
                    ninja: bool) -> list[str]:
    """The configure command: no build type (``-O0``, as colcon builds by default), tests off,
    Ninja when there is one, and ``generators_script`` (``GENERATORS_CMAKE``) where CMake runs it."""
    cmd = ["cmake", "-S", str(source), "-B", str(build), f"-DCMAKE_PREFIX_PATH={prefix}",
           f"-DCMAKE_INSTALL_PREFIX={prefix}", f"-DPython3_EXECUTABLE={sys.executable}", "-DBUILD_TESTING=OFF"]
    if ninja:
        cmd += ["-G", "Ninja"]
    if generators_script is not None:
        cmd.append(f"-DCMAKE_PROJECT_TOP_LEVEL_INCLUDES={generators_script}")
    return cmd


def parse_cmake_version(text: str) -> tuple[int, int]:
    """(major, minor) from ``cmake --version``'s output; (0, 0) when it names none."""
    found = re.search(r"version (\d+)\.(\d+)", text)
    return (int(found.group(1)), int(found.group(2))) if found else (0, 0)


def say(line: str) -> None:
    """Print a line in one write: packages building side by side never split each other's."""
    sys.stdout.write(line + "\n")
    sys.stdout.flush()


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
            replace_file(f, new.encode(errors="surrogateescape"))
            changed += 1
    return changed


def replace_file(path: Path, data: bytes) -> None:
    """Give ``path`` new content as a new file renamed over it: an installer that hard-links
    files from its cache (uv) shares the old one with every other venv."""
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_bytes(data)
    shutil.copymode(path, tmp)
    os.replace(tmp, path)


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


def build_package(pkg: Package, prefix: Path, env: dict[str, str], build_dir: Path, jobs: int,
                  generators_script: Path | None) -> list[str]:
    """Configure, build and install ``pkg`` into ``prefix``; the installed files, relative to it."""
    build = build_dir / pkg.name
    # A clean configure every time: cheap next to the compile, and immune to stale caches.
    if build.exists():
        shutil.rmtree(build)
    build.mkdir(parents=True)
    log = build / "build.log"
    say(f"{pkg.name}: building with cmake (log: {log})")
    configure = cmake_arguments(pkg.path, build, prefix, generators_script, ninja=shutil.which("ninja") is not None)
    run_step(pkg, "configure", configure, env, log)
    run_step(pkg, "build", ["cmake", "--build", str(build), "--parallel", str(jobs)], env, log)
    run_step(pkg, "install", ["cmake", "--install", str(build)], env, log)
    files = dict.fromkeys(Path(line) for line in (build / "install_manifest.txt").read_text().splitlines())
    outside = [str(path) for path in files if not path.is_relative_to(prefix)]
    if outside:
        raise BuildError(f"interface package '{pkg.name}': cmake installed {outside[0]}, outside {prefix}")
    return [str(path.relative_to(prefix)) for path in files]


def archive(pkg: Package, key: str, prefix: Path, files: list[str]) -> bytes:
    """The installed ``files`` of ``pkg`` as a gzipped tar, with its marker (the prefix they were
    installed for, whose mentions an install elsewhere rewrites)."""
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w:gz", compresslevel=1) as tar:
        for name in files:
            tar.add(prefix / name, arcname=name, recursive=False)
        marker = json.dumps({"key": key, "prefix": str(prefix), "files": files}, indent=1).encode()
        info = tarfile.TarInfo(f"share/{pkg.name}/{MARKER}")
        info.size, info.mtime = len(marker), int(time.time())
        tar.addfile(info, io.BytesIO(marker))
    return buffer.getvalue()


def read_marker(prefix: Path, name: str) -> dict[str, Any]:
    """The marker of package ``name`` installed in ``prefix``; {} when there is none."""
    try:
        marker: dict[str, Any] = json.loads((prefix / "share" / name / MARKER).read_text())
        return marker
    except (OSError, ValueError):
        return {}


def install_archive(pkg: Package, path: Path, prefix: Path) -> None:
    """Install an ``archive`` into ``prefix``: each file renamed into place (a process that has
    the old library loaded keeps it), mentions of the prefix it was built for rewritten, and the
    files of the version it replaces that it does not have removed."""
    old_files = set(read_marker(prefix, pkg.name).get("files", []))
    staging = Path(tempfile.mkdtemp(prefix=f".{pkg.name}-", dir=prefix))
    try:
        with tarfile.open(path) as tar:
            tar.extractall(staging, filter="data")
        marker_path = Path("share") / pkg.name / MARKER
        marker = json.loads((staging / marker_path).read_text())
        built_for, files = marker["prefix"], marker["files"]
        for name in files:
            staged = staging / name
            if built_for != str(prefix):
                data = staged.read_bytes()
                if b"\0" not in data and built_for.encode() in data:
                    staged.write_bytes(data.replace(built_for.encode(), str(prefix).encode()))
            (prefix / name).parent.mkdir(parents=True, exist_ok=True)
            os.replace(staged, prefix / name)
        for name in old_files - set(files):
            (prefix / name).unlink(missing_ok=True)
        (staging / marker_path).write_text(json.dumps({**marker, "prefix": str(prefix)}, indent=1))
        os.replace(staging / marker_path, prefix / marker_path)
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def forget_cached(key: str) -> None:
    """Drop the cache's archive ``key`` (``--force``, or one that installs but does not load)."""
    root = disk_cache.cache_dir()
    if root is not None:
        (root / CACHE_KIND / key).unlink(missing_ok=True)


@dataclass(frozen=True)
class Build:
    """How every package of one run builds."""
    prefix: Path
    env: dict[str, str]
    build_dir: Path
    jobs: int
    generators_script: Path | None


def provide(pkg: Package, key: str, how: Build, force: bool) -> str:
    """Make ``prefix`` hold the build ``key`` of ``pkg`` (see the module's docstring, step 2);
    the line that says which way."""
    start = time.monotonic()
    if not force and read_marker(how.prefix, pkg.name).get("key") == key and types_load(pkg, how.env):
        return f"{pkg.name}: up to date"
    built = []

    def compute() -> bytes:
        files = build_package(pkg, how.prefix, how.env, how.build_dir, how.jobs, how.generators_script)
        built.append(True)
        return archive(pkg, key, how.prefix, files)

    def install(path: str) -> None:
        install_archive(pkg, Path(path), how.prefix)

    if force:
        forget_cached(key)
    disk_cache.cached_file(CACHE_KIND, key, compute, install)
    loads = types_load(pkg, how.env)
    if not loads and not built:  # a cached build that does not load here: build it anew
        forget_cached(key)
        disk_cache.cached_file(CACHE_KIND, key, compute, install)
        loads = types_load(pkg, how.env)
    if not loads:
        raise BuildError(f"interface package '{pkg.name}': built and installed into {how.prefix}, "
                         f"but its Python types do not load (try: {sys.executable} -c "
                         f"'import {pkg.name}.{pkg.interfaces()[0][0]}')")
    if built:
        return f"{pkg.name}: built in {time.monotonic() - start:.1f} s"
    return f"{pkg.name}: installed from the cache in {time.monotonic() - start:.1f} s"


def toolchain_facts(cmake_version: tuple[int, int]) -> str:
    """What a build depends on beyond its sources: the interpreter and its ABI, the installed
    ROS 2 wheels, empy and numpy, cmake, and this file (the build recipe). Not the venv's path:
    a build installs into any venv of the same interpreter."""
    wheels = sorted(f"{d.metadata['Name']}=={d.version}" for d in metadata.distributions()
                    if is_build_input(d.metadata["Name"] or ""))
    return "\n".join([sys.version, sys.base_prefix, sysconfig.get_config_var("SOABI") or "",
                      f"cmake {cmake_version}", hashlib.sha256(Path(__file__).read_bytes()).hexdigest(), *wheels])


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
                        help="cmake build directories (default: <venv>/build/objective-interfaces)")
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
        wanted = []
        for pkg in packages:
            if args.packages and pkg.name not in args.packages:
                continue
            elsewhere = provided_elsewhere(pkg.name, prefix, dict(os.environ))
            if elsewhere is not None and pkg.name not in args.packages:
                print(f"{pkg.name}: skipped, {elsewhere} has it (name it to build this copy, which would hide that one)",
                      flush=True)
                continue
            wanted.append(pkg)
        if wanted:
            provide_all(wanted, prefix, build_dir, args.force)
    except (BuildError, OSError) as exc:
        print(f"build_interfaces: FAILED: {exc}", file=sys.stderr)
        return 1
    return 0


def provide_all(packages: list[Package], prefix: Path, build_dir: Path, force: bool) -> None:
    """``provide`` each package, a dependency level at a time, the packages of a level side by
    side; the first failure raised once the others have ended."""
    cmake_version = parse_cmake_version(subprocess.run(["cmake", "--version"], capture_output=True, text=True).stdout)
    generators_script = None
    if cmake_version >= GENERATORS_CMAKE_SINCE:
        build_dir.mkdir(parents=True, exist_ok=True)
        generators_script = build_dir / "python-generators-only.cmake"
        generators_script.write_text(GENERATORS_CMAKE)
    else:
        print(f"build_interfaces: cmake {cmake_version[0]}.{cmake_version[1]} runs every generator, "
              "C++ ones too (cmake >= 3.24 builds only what Python uses)", flush=True)
    toolchain = toolchain_facts(cmake_version)
    keys: dict[str, str] = {}
    for pkg in dependency_order(packages):
        keys[pkg.name] = disk_cache.content_key(source_hash(pkg, toolchain), *sorted(
            keys[d] for d in pkg.depends if d in keys))
    for level in dependency_levels(packages):
        workers = min(MAX_JOBS, len(level))
        how = Build(prefix, build_env(prefix), build_dir, max(1, MAX_JOBS // workers), generators_script)
        with ThreadPoolExecutor(max_workers=workers) as pool:
            futures = [pool.submit(provide, pkg, keys[pkg.name], how, force) for pkg in level]
            failures = []
            for future in as_completed(futures):
                try:
                    say(future.result())
                except (BuildError, OSError) as exc:
                    failures.append(exc)
        if failures:
            raise failures[0]


COMMAND = Command("build the ROS 2 interface packages shipped in runtime/io/ros/interfaces into this venv",
                  add_arguments, build, needs_registry=False)

if __name__ == "__main__":
    sys.exit(main())
