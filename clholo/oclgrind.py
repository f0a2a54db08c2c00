"""Run clholo under the Oclgrind OpenCL simulator and collect what it reports.

Oclgrind (Debian/Ubuntu package ``oclgrind``) simulates an OpenCL device and reports invalid
(out-of-bounds) reads and writes, data races between work-items (``OCLGRIND_DATA_RACES=1``),
work-group divergence at barriers, invalid use of read-only/write-only buffers and, with
``OCLGRIND_UNINITIALIZED=1``, uses of uninitialised values. It plugs in as a second OpenCL
platform through the ICD loader: a folder holding one file ``oclgrind.icd`` with the full path
of ``liboclgrind-rt-icd.so``, named by ``OCL_ICD_VENDORS`` (pyopencl's wheel bundles
ocl-icd, which honours it: with a folder the loader lists Oclgrind beside the wheel's own PoCL),
and ``CLHOLO_DEVICE=oclgrind`` picks it. Oclgrind's messages go to the file named by
``OCLGRIND_LOG`` instead of stderr, so a clean run is an empty log.

``python -m clholo.oclgrind`` runs ``clholo selftest --quick`` (every kernel family against its
NumPy reference, :mod:`clholo.selftest`) that way and exits 1 on any report or failed check;
``python -m clholo.oclgrind -- CMD ...`` runs another command. ``tests/test_oclgrind.py`` and CI
use :func:`run_under_oclgrind`.

Known limitation (Debian's Oclgrind 21.10): ``OCLGRIND_UNINITIALIZED=1`` is not usable on
clholo's kernels. Its shadow-value tracking reports a vector built from lanes of an initialised
one, such as ``(float2)(x.y, -x.x)``, as uninitialised (a false positive, shown by a two-line
kernel on a host-initialised buffer), and it aborts with "OCLGRIND FATAL ERROR ... Unsupported
instruction: freeze" on the LLVM ``freeze`` instruction that clang's optimiser emits (for
example in the GPU FFT's ``fft_lines``), after which the results are wrong and the process may
crash. See ``docs/selftest.md``.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import tempfile
from dataclasses import dataclass, field
from typing import Dict, List, Mapping, Optional, Sequence

__all__ = ["ICD_CANDIDATES", "find_icd", "oclgrind_env", "find_reports", "OclgrindRun",
           "run_under_oclgrind", "selftest_command", "main"]

#: Where distributions install Oclgrind's ICD library (``dpkg -L oclgrind`` on Debian).
ICD_CANDIDATES = (
    "/usr/lib/oclgrind/liboclgrind-rt-icd.so",
    "/usr/lib/x86_64-linux-gnu/oclgrind/liboclgrind-rt-icd.so",
    "/usr/lib/aarch64-linux-gnu/oclgrind/liboclgrind-rt-icd.so",
    "/usr/lib64/oclgrind/liboclgrind-rt-icd.so",
    "/usr/local/lib/liboclgrind-rt-icd.so",
    "/usr/local/lib/oclgrind/liboclgrind-rt-icd.so",
)

# The first line of each kind of Oclgrind report (its Logger, MemCheck, RaceDetector,
# Uninitialized and API-check plugins, and fatal errors). Anything at all in the log counts as
# a report too; these catch reports that reach stderr when the log cannot be used.
_REPORT_RE = re.compile(
    r"Invalid (read|write) of size|Invalid (read|write) (from|to) |Invalid memory (load|store)"
    r"|data race at |Work-group divergence|Work-item divergence|divergence detected"
    r"|Uninitiali[sz]ed value|Controlflow depends on uninitiali[sz]ed"
    r"|OCLGRIND FATAL ERROR|Oclgrind - OpenCL runtime error|runtime error detected"
    r"|errors? suppressed|Unsupported instruction", re.IGNORECASE)


# With OCLGRIND_CHECK_API=1 Oclgrind also reports every failed API call. pyopencl probes device
# properties an OpenCL 1.2 device does not have (its array arithmetic asks for newer
# clGetDeviceInfo names and handles the error), which Oclgrind reports as below: such probes are
# not errors of clholo's, and they are counted apart (OclgrindRun.ignored).
_PROBE_RE = re.compile(r"Function:\s*clGetDeviceInfo\s+Error:\s*CL_INVALID_VALUE\s+"
                       r"For argument 'param_name'\s*$")


def find_icd() -> Optional[str]:
    """Path of Oclgrind's ICD library (``$OCLGRIND_ICD`` if set), or None when not installed."""
    env = os.environ.get("OCLGRIND_ICD")
    for path in ((env,) if env else ()) + ICD_CANDIDATES:
        if path and os.path.isfile(path):
            return path
    return None


def oclgrind_env(folder: str, *, icd: Optional[str] = None, data_races: bool = True,
                 uninitialized: bool = False, log: Optional[str] = None,
                 base: Optional[Mapping[str, str]] = None) -> Dict[str, str]:
    """Environment that makes clholo run on Oclgrind; writes ``folder/oclgrind.icd``.

    Parameters
    ----------
    folder : str
        An existing folder for the ``.icd`` file (``OCL_ICD_VENDORS`` points at it).
    icd : str, optional
        Path of ``liboclgrind-rt-icd.so``; default :func:`find_icd`.
    data_races : bool
        ``OCLGRIND_DATA_RACES=1`` (race detection).
    uninitialized : bool
        ``OCLGRIND_UNINITIALIZED=1`` (see the module's note on Oclgrind 21.10).
    log : str, optional
        ``OCLGRIND_LOG``: Oclgrind's messages go to this file instead of stderr.
    base : mapping, optional
        Environment to start from (default ``os.environ``).

    Raises
    ------
    FileNotFoundError
        Oclgrind is not installed (with the install command).
    """
    icd = icd or find_icd()
    if not icd or not os.path.isfile(icd):
        raise FileNotFoundError(
            "Oclgrind's ICD library liboclgrind-rt-icd.so was not found (looked in "
            f"{', '.join(ICD_CANDIDATES)}); install it with `apt-get install oclgrind` or point "
            "OCLGRIND_ICD at it")
    with open(os.path.join(folder, "oclgrind.icd"), "w", encoding="utf-8") as f:
        f.write(os.path.abspath(icd) + "\n")
    env = dict(os.environ if base is None else base)
    env.pop("PYOPENCL_CTX", None)
    env.update({"OCL_ICD_VENDORS": os.path.abspath(folder), "CLHOLO_DEVICE": "oclgrind",
                "OCLGRIND_CHECK_API": "1", "PYOPENCL_NO_CACHE": "1"})
    for var, on in (("OCLGRIND_DATA_RACES", data_races),
                    ("OCLGRIND_UNINITIALIZED", uninitialized)):
        if on:
            env[var] = "1"
        else:
            env.pop(var, None)
    if log:
        env["OCLGRIND_LOG"] = os.path.abspath(log)
    return env


def find_reports(text: str) -> List[str]:
    """The Oclgrind reports in ``text``: blank-line separated blocks whose lines match one of
    Oclgrind's report headings (invalid accesses, data races, divergence, uninitialised
    values, API errors, fatal errors)."""
    return [b for b in _blocks(text) if _REPORT_RE.search(b)]


def _blocks(text: str) -> List[str]:
    return [b.strip() for b in re.split(r"\n\s*\n", text) if b.strip()]


def _is_probe(report: str) -> bool:
    return "OpenCL runtime error" in report and bool(_PROBE_RE.search(report))


@dataclass
class OclgrindRun:
    """Result of :func:`run_under_oclgrind`."""

    argv: List[str]
    returncode: int
    stdout: str
    stderr: str
    log: str
    reports: List[str] = field(default_factory=list)
    ignored: List[str] = field(default_factory=list)  # pyopencl's device-property probes

    @property
    def clean(self) -> bool:
        """Exit status 0 and not a single Oclgrind report."""
        return self.returncode == 0 and not self.reports

    def summary(self, max_reports: int = 5) -> str:
        """A readable account (for assertion messages and the command line)."""
        lines = [f"command: {' '.join(self.argv)}", f"exit status {self.returncode}, "
                 f"{len(self.reports)} Oclgrind report(s) ({len(self.ignored)} failed "
                 f"clGetDeviceInfo probes of pyopencl's not counted)"]
        for r in self.reports[:max_reports]:
            lines += ["--- report ---", r]
        if self.returncode != 0:
            lines += ["--- stdout (tail) ---", self.stdout[-3000:],
                      "--- stderr (tail) ---", self.stderr[-3000:]]
        return "\n".join(lines)


def selftest_command(json_path: Optional[str] = None) -> List[str]:
    """``clholo selftest --quick [--json FILE]`` with this Python interpreter."""
    cmd = [sys.executable, "-c", "import sys; from clholo.cli import main; sys.exit(main())",
           "selftest", "--quick"]
    return cmd + (["--json", json_path] if json_path else [])


def run_under_oclgrind(argv: Sequence[str], *, data_races: bool = True,
                       uninitialized: bool = False, timeout: Optional[float] = 600,
                       cwd: Optional[str] = None,
                       env: Optional[Mapping[str, str]] = None) -> OclgrindRun:
    """Run ``argv`` in a subprocess on the Oclgrind device and collect its reports.

    Reports are everything Oclgrind wrote to its log (``OCLGRIND_LOG``) plus any report found
    on stderr (:func:`find_reports`).

    Raises
    ------
    FileNotFoundError
        Oclgrind is not installed.
    subprocess.TimeoutExpired
        The command ran longer than ``timeout`` seconds.
    """
    with tempfile.TemporaryDirectory(prefix="clholo-oclgrind-") as tmp:
        log = os.path.join(tmp, "oclgrind.log")
        run_env = oclgrind_env(tmp, data_races=data_races, uninitialized=uninitialized,
                               log=log, base=env)
        proc = subprocess.run(list(argv), env=run_env, cwd=cwd, capture_output=True, text=True,
                              timeout=timeout)
        log_text = ""
        if os.path.exists(log):
            with open(log, encoding="utf-8", errors="replace") as f:
                log_text = f.read()
    found = _blocks(log_text) + find_reports(proc.stderr)
    reports = [r for r in found if not _is_probe(r)]
    ignored = [r for r in found if _is_probe(r)]
    return OclgrindRun(list(argv), proc.returncode, proc.stdout, proc.stderr, log_text, reports,
                       ignored)


def main(argv: Optional[Sequence[str]] = None) -> int:
    """``python -m clholo.oclgrind [--uninitialized] [--no-races] [-- CMD ...]``."""
    import argparse

    parser = argparse.ArgumentParser(
        prog="python -m clholo.oclgrind",
        description="run `clholo selftest --quick` (or CMD) on the Oclgrind simulator and "
                    "list what it reports; exit 1 on any report or failure")
    parser.add_argument("--uninitialized", action="store_true",
                        help="also report uninitialised values (unreliable in Oclgrind 21.10)")
    parser.add_argument("--no-races", action="store_true", help="no data-race detection")
    parser.add_argument("--timeout", type=float, default=1800, help="seconds (default 1800)")
    parser.add_argument("cmd", nargs="*", help="command to run instead of the self-test")
    args = parser.parse_args(argv)
    cmd = args.cmd or selftest_command()
    try:
        result = run_under_oclgrind(cmd, data_races=not args.no_races,
                                    uninitialized=args.uninitialized, timeout=args.timeout)
    except FileNotFoundError as exc:
        print(f"clholo.oclgrind: {exc}", file=sys.stderr)
        return 2
    sys.stdout.write(result.stdout)
    print(result.summary(max_reports=20), file=sys.stderr)
    return 0 if result.clean else 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
