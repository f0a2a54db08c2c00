"""The mutation campaign (tests/mutation/run_mutants.py) stays runnable: every mutant's find text
occurs exactly once in the file it edits. Kernels and host code get rewritten (the Adam step in
float16, the composite launch behind one helper), and a find text that no longer occurs makes a
mutant a no-op that the campaign would report as a problem only when someone runs it."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_every_mutant_find_text_occurs_once():
    res = subprocess.run([sys.executable, str(ROOT / "tests" / "mutation" / "run_mutants.py"),
                          "--check"], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert res.returncode == 0, res.stdout + res.stderr
    assert res.stdout.strip().endswith("0 problem(s)"), res.stdout
