"""A generated controller compiled by the system C compiler and called through ``ctypes``.

``compile_controller`` builds ``wmr_controller.c`` into a shared library
together with a small batch driver (``wmr_batch_init``/``wmr_batch_step``:
one call steps ``N`` controllers), so that a host loop over many runs pays
one foreign call per period, not one per run. The driver is the test host's,
not part of the exported files.
"""

from __future__ import annotations

import ctypes
import os
import shutil
import subprocess
import tempfile
import weakref
from pathlib import Path
from typing import Any

import numpy as np

from wmr_jax._src.checks import check_bool
from wmr_jax._src.export.codegen import HEADER, SOURCE

# The flags the exported files must compile cleanly with.
CFLAGS = ("-std=c99", "-Wall", "-Wextra", "-pedantic", "-Werror")
# The optimisation flags compile_controller takes (GCC's and Clang's).
OPTIMISE = ("-O", "-O0", "-O1", "-O2", "-O3", "-Os", "-Oz", "-Og", "-Ofast")
# Multiply-adds fused where the CPU has them, as XLA:CPU compiles the JAX step.
CONTRACT = ("-march=native", "-ffp-contract=fast")
SANITIZE = ("-fsanitize=address,undefined", "-fno-omit-frame-pointer", "-fno-sanitize-recover=all")

_BATCH_DRIVER = r"""
#include <stddef.h>
#include "wmr_controller.h"

size_t wmr_batch_size(void) { return sizeof(wmr_controller); }

void wmr_batch_init(wmr_controller *c, size_t n, const double *refs, const int *latency)
{
    size_t i;
    for (i = 0; i < n; ++i)
        wmr_init(&c[i], &refs[3 * i], latency[i]);
}

void wmr_batch_step(wmr_controller *c, size_t n, const double *measured, double *commands)
{
    size_t i;
    for (i = 0; i < n; ++i)
        wmr_step(&c[i], &measured[3 * i], &commands[2 * i]);
}

/* Steps one controller `repeats` times over `count` measurements, for timing. */
void wmr_batch_repeat(wmr_controller *c, const double *measured, size_t count, size_t repeats,
                      double *command)
{
    size_t r, k;
    for (r = 0; r < repeats; ++r)
        for (k = 0; k < count; ++k)
            wmr_step(c, &measured[3 * k], command);
}
"""


def compiler() -> str | None:
    """The system C compiler (``$CC``, else ``cc``), or ``None`` where there is none."""
    name = os.environ.get("CC", "cc")
    return shutil.which(name)


def _run(command: list[str]) -> None:
    done = subprocess.run(command, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise RuntimeError(
            f"{' '.join(command)} failed ({done.returncode}):\n{done.stderr.strip()}"
        )


def sanitizers_work(cc: str | None = None) -> bool:
    """Whether ``cc`` builds and runs a program with ``-fsanitize=address,undefined``."""
    cc = cc or compiler()
    if cc is None:
        return False
    with tempfile.TemporaryDirectory() as tmp:
        src, exe = Path(tmp, "probe.c"), Path(tmp, "probe")
        src.write_text("int main(void) { return 0; }\n")
        try:
            _run([cc, *SANITIZE, str(src), "-o", str(exe)])
            return subprocess.run([str(exe)], check=False).returncode == 0
        except (RuntimeError, OSError):
            return False


class CompiledController:
    """A compiled ``wmr_controller``: its C functions, and ``N`` controllers stepped at once.

    Attributes:
        folder: the folder of the exported files.
        library: the shared library's path.
        lib: the ``ctypes.CDLL``.
        size: ``sizeof(wmr_controller)``, bytes.
        period: ``wmr_period()``, s.
    """

    def __init__(self, folder: Path, library: Path):
        self.folder, self.library = folder, library
        lib = ctypes.CDLL(str(library))
        double_p = np.ctypeslib.ndpointer(np.float64, flags="C_CONTIGUOUS")
        int_p = np.ctypeslib.ndpointer(np.intc, flags="C_CONTIGUOUS")
        lib.wmr_size.restype = ctypes.c_size_t
        lib.wmr_period.restype = ctypes.c_double
        lib.wmr_init.argtypes = [ctypes.c_void_p, double_p, ctypes.c_int]
        lib.wmr_step.argtypes = [ctypes.c_void_p, double_p, double_p]
        lib.wmr_batch_init.argtypes = [ctypes.c_void_p, ctypes.c_size_t, double_p, int_p]
        lib.wmr_batch_step.argtypes = [ctypes.c_void_p, ctypes.c_size_t, double_p, double_p]
        lib.wmr_batch_repeat.argtypes = [
            ctypes.c_void_p, double_p, ctypes.c_size_t, ctypes.c_size_t, double_p,
        ]  # fmt: skip
        self.lib = lib
        self.size = int(lib.wmr_size())
        self.period = float(lib.wmr_period())
        self._states = None
        self._n = 0

    def start(self, refs: Any, latency: Any) -> None:
        """``wmr_init`` ``N`` controllers: goals ``refs (N, 3)``, ``latency`` an int or ``(N,)``."""
        refs = np.ascontiguousarray(refs, dtype=np.float64).reshape(-1, 3)
        n = len(refs)
        latency = np.ascontiguousarray(np.broadcast_to(latency, (n,)), dtype=np.intc)
        self._states = ctypes.create_string_buffer(max(1, n) * self.size)
        self._n = n
        self.lib.wmr_batch_init(self._states, n, refs, latency)

    def step(self, measured: Any) -> np.ndarray:
        """``wmr_step`` each controller with its row of ``measured (N, 3)``; return ``(N, 2)``."""
        measured = np.ascontiguousarray(measured, dtype=np.float64).reshape(self._n, 3)
        out = np.empty((self._n, 2))
        self.lib.wmr_batch_step(self._states, self._n, measured, out)
        return out

    def state_address(self, i: int) -> int:
        """The address of controller ``i``'s ``wmr_controller`` (for tests that set its fields)."""
        return ctypes.addressof(self._states) + i * self.size


def compile_controller(
    folder: str | os.PathLike,
    *,
    build: str | os.PathLike | None = None,
    optimise: str = "-O2",
    sanitize: bool = False,
    contract: bool = False,
) -> CompiledController:
    """Compile ``folder/wmr_controller.c`` with the batch driver into a shared library; load it.

    Args:
        folder: the folder ``wmr-jax export`` wrote.
        build: where to put the library (default: a temporary folder, removed
            with the returned controller).
        optimise: the optimisation flag, one of ``OPTIMISE``.
        sanitize: build with ``-fsanitize=address,undefined`` (the library
            then needs the sanitizer's runtime loaded first: see the tests).
        contract: fuse multiplications and additions into FMAs for this
            machine's CPU (``CONTRACT``), as XLA:CPU does: the same rounding
            as the JAX step, so that even states exactly on a switch of the
            law fall on the same side. ISO C's default (``False``) rounds
            every operation; it differs from the JAX step in the last bits.

    Raises:
        ValueError: for a bad argument, a folder without the exported files,
            or no C compiler.
        RuntimeError: the compiler's message, if the files do not compile.
    """
    sanitize, contract = check_bool("sanitize", sanitize), check_bool("contract", contract)
    for name, value in (("folder", folder), ("build", build)):
        if not (isinstance(value, (str, os.PathLike)) or (name == "build" and value is None)):
            raise ValueError(f"{name} = {value!r:.80} is not allowed; allowed: a path")
    if not (isinstance(optimise, str) and optimise in OPTIMISE):
        raise ValueError(
            f"optimise = {optimise!r:.80} is not allowed; allowed: {', '.join(OPTIMISE)}"
        )
    folder = Path(folder)
    for name in (HEADER, SOURCE):
        if not (folder / name).is_file():
            raise ValueError(
                f"folder {os.fspath(folder)!r} has no {name}; allowed: a folder of wmr-jax export"
            )
    cc = compiler()
    if cc is None:
        raise ValueError("no C compiler found (cc, or $CC); allowed: a machine with one")
    # A library of its own folder: removed with the CompiledController that loaded it
    # (a finaliser, not a TemporaryDirectory, which warns when it is collected).
    scratch = tempfile.mkdtemp(prefix="wmr_export_") if build is None else None
    build = Path(scratch if scratch is not None else build)
    build.mkdir(parents=True, exist_ok=True)
    driver = build / "wmr_batch.c"
    driver.write_text(_BATCH_DRIVER)
    library = build / "libwmr_controller.so"
    flags = [*CFLAGS, optimise, "-fPIC", "-shared", f"-I{folder}"]
    if sanitize:
        flags += list(SANITIZE)
    if contract:
        flags += list(CONTRACT)
    try:
        _run([cc, *flags, str(folder / SOURCE), str(driver), "-o", str(library), "-lm"])
        compiled = CompiledController(folder, library)
    except BaseException:
        if scratch is not None:
            shutil.rmtree(scratch, ignore_errors=True)
        raise
    if scratch is not None:
        weakref.finalize(compiled, shutil.rmtree, scratch, ignore_errors=True)
    return compiled
