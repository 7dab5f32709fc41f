"""Your own policy in one file: a backend factory named ``FILE.py:NAME`` or ``MODULE:NAME``.

The factory is called as the installed backends are (``objective.policy_backends``):
``NAME(options: BackendOptions) -> PolicyBackend``, where a ``PolicyBackend`` has a ``name`` and
``load()``, ``warmup(request)`` and ``infer(request)`` (``policy.backend``). ``objective serve
--backend`` and ``objective run/eval --policy`` take the same spec, so a model tried in one file
needs no package::

    # my_policy.py
    from policy.backend import PolicyResponse, Status

    class Hold:
        name = "hold"
        def load(self): ...
        def warmup(self, request): ...
        def infer(self, request):
            ...

    def make(options):
        return Hold()

    objective serve --backend my_policy.py:make

A file that cannot be imported, a name it does not define, a factory that raises and one that
returns something else than a backend are each a ``FactoryError`` naming the file and the factory.
"""
from __future__ import annotations

import importlib
import importlib.util
import re
import sys
from pathlib import Path
from typing import Any, Callable

from runtime.errors import OptionError
from runtime.io.interrupt import describe_error, raised_by_code

from .backend import PolicyBackend

_MODULE_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*")
BACKEND_METHODS = ("load", "warmup", "infer")


class FactoryError(OptionError):
    """A ``FILE.py:NAME`` or ``MODULE:NAME`` that gives no backend; the message says why."""


def is_factory_spec(text: str) -> bool:
    """True for ``FILE.py:NAME`` and ``MODULE:NAME`` (NAME a Python identifier)."""
    where, sep, name = text.rpartition(":")
    if not sep or not name.isidentifier():
        return False
    return where.endswith(".py") or _MODULE_NAME.fullmatch(where) is not None


def factory_file(text: str) -> Path | None:
    """The file of a ``FILE.py:NAME`` spec (None for ``MODULE:NAME``)."""
    where = text.rpartition(":")[0]
    return Path(where).expanduser() if where.endswith(".py") else None


def load_factory(text: str) -> Callable[..., Any]:
    """The callable ``text`` names; FactoryError when the file or module or the name is not there."""
    where, _, name = text.rpartition(":")
    module = _import_file(Path(where).expanduser(), text) if where.endswith(".py") else _import_module(where, text)
    factory = getattr(module, name, None)
    if factory is None:
        defined = sorted(n for n, v in vars(module).items() if callable(v) and not n.startswith("_"))
        raise FactoryError(f"policy factory {text}: {where} defines no '{name}' "
                           f"(callables it defines: {', '.join(defined) or 'none'})")
    if not callable(factory):
        raise FactoryError(f"policy factory {text}: '{name}' is a {type(factory).__name__}, not a function")
    result: Callable[..., Any] = factory
    return result


def build_backend(text: str, options: Any) -> PolicyBackend:
    """The backend ``text``'s factory builds from ``options`` (a ``policy.server.BackendOptions``)."""
    factory = load_factory(text)
    try:
        backend = factory(options)
    except BaseException as err:
        if not raised_by_code(err):
            raise
        raise FactoryError(f"policy factory {text} raised {describe_error(err)}") from None
    missing = [m for m in BACKEND_METHODS if not callable(getattr(backend, m, None))]
    if missing or not isinstance(getattr(backend, "name", None), str):
        lacks = ", ".join(f"{m}()" for m in missing) or "a name (str)"
        raise FactoryError(f"policy factory {text} returned {type(backend).__name__}, not a policy backend "
                           f"(it lacks {lacks}; a backend has name, load(), warmup(request) and infer(request))")
    result: PolicyBackend = backend
    return result


def _import_file(path: Path, text: str) -> Any:
    if not path.is_file():
        raise FactoryError(f"policy factory {text}: no such file {path}")
    module_name = f"objective_policy_{re.sub(r'[^0-9A-Za-z_]', '_', path.stem)}"
    spec = importlib.util.spec_from_file_location(module_name, path)
    if spec is None or spec.loader is None:
        raise FactoryError(f"policy factory {text}: {path} cannot be imported as Python")
    module = importlib.util.module_from_spec(spec)
    sys.modules[module_name] = module  # dataclasses and pickling look their module up by name
    try:
        spec.loader.exec_module(module)
    except BaseException as err:  # a sys.exit() at import is the file's error too
        sys.modules.pop(module_name, None)
        if not raised_by_code(err):
            raise
        raise FactoryError(f"policy factory {text}: importing {path} raised {describe_error(err)}") from None
    return module


def _import_module(name: str, text: str) -> Any:
    try:
        return importlib.import_module(name)
    except ModuleNotFoundError as err:
        if err.name == name or name.startswith(f"{err.name}."):
            raise FactoryError(f"policy factory {text}: no module named '{name}' (a file is named FILE.py:NAME)") from None
        raise FactoryError(f"policy factory {text}: importing {name} raised {describe_error(err)}") from err
    except BaseException as err:  # a SyntaxError's text names the file and line
        if not raised_by_code(err):
            raise
        raise FactoryError(f"policy factory {text}: importing {name} raised {describe_error(err)}") from None
