"""A small mutation tester: does the test suite notice when the code is wrong?

Each mutant changes one thing in one module (a comparison flipped or made non-strict, an
arithmetic or boolean operator swapped, an integer constant moved by one, True/False swapped,
a `not` dropped, a call statement, `raise` or `return` value removed) and the module's tests
run against it. A mutant that no test fails "survives": either the tests miss a behaviour or
the mutant is equivalent (changes nothing observable). docs/testing.md lists the survivors of
the recorded run and what was done about them.

Mutants run in a private copy of the package (a temp directory first on PYTHONPATH), so the
working tree is never touched and other processes keep importing the real code.

    python bench/mutate.py --module protocol/pcapng.py --tests tests/test_pcapng_malformed.py
    python bench/mutate.py --preset all --max 40 --json      # the recorded run (sampled)
"""

from __future__ import annotations

import argparse
import ast
import copy
import json
import os
import random
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = {"protocol": "protocol", "firmware_py": "firmware", "emulator": "emulator", "host": "host",
            "campaigns": "campaigns"}
PRESETS = {
    "pcapng": ("protocol/pcapng.py", ["tests/test_pcapng_malformed.py", "tests/test_wireshark.py"]),
    "frames": ("protocol/frames/codec.py", ["tests/test_frames.py", "tests/test_accel.py"]),
    "uconnect": ("protocol/uconnect/decoder.py", ["tests/test_uconnect_decoder.py", "tests/test_accel.py"]),
    "loop": ("host/homing/loop.py", ["tests/test_homing.py"]),
}
SWAP = {ast.Lt: ast.LtE, ast.LtE: ast.Lt, ast.Gt: ast.GtE, ast.GtE: ast.Gt, ast.Eq: ast.NotEq, ast.NotEq: ast.Eq,
        ast.In: ast.NotIn, ast.NotIn: ast.In, ast.Is: ast.IsNot, ast.IsNot: ast.Is,
        ast.Add: ast.Sub, ast.Sub: ast.Add, ast.Mult: ast.FloorDiv, ast.Div: ast.Mult, ast.FloorDiv: ast.Mult,
        ast.And: ast.Or, ast.Or: ast.And, ast.BitAnd: ast.BitOr, ast.BitOr: ast.BitAnd,
        ast.LShift: ast.RShift, ast.RShift: ast.LShift, ast.Mod: ast.Mult}


def mutants(tree: ast.Module) -> list[tuple[int, str, int]]:
    """(node index in ast.walk order, description, line) of every mutation of ``tree``."""
    out = []
    for i, node in enumerate(ast.walk(tree)):
        line = getattr(node, "lineno", 0)
        if isinstance(node, ast.Compare) and type(node.ops[0]) in SWAP:
            out.append((i, f"{type(node.ops[0]).__name__} -> {SWAP[type(node.ops[0])].__name__}", line))
        elif isinstance(node, (ast.BinOp, ast.AugAssign)) and type(node.op) in SWAP:
            out.append((i, f"{type(node.op).__name__} -> {SWAP[type(node.op)].__name__}", line))
        elif isinstance(node, ast.BoolOp):
            out.append((i, f"{type(node.op).__name__} -> {SWAP[type(node.op)].__name__}", line))
        elif isinstance(node, ast.Constant) and type(node.value) is bool:
            out.append((i, f"{node.value} -> {not node.value}", line))
        elif isinstance(node, ast.Constant) and type(node.value) is int:
            out.append((i, f"{node.value} -> {node.value + 1}", line))
        elif isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.Not):
            out.append((i, "not x -> x", line))
        elif isinstance(node, ast.Expr) and isinstance(node.value, ast.Call):
            out.append((i, f"drop call {ast.unparse(node.value)[:40]}", line))
        elif isinstance(node, ast.Raise):
            out.append((i, "drop raise", line))
        elif isinstance(node, ast.Return) and node.value is not None and not isinstance(node.value, ast.Constant):
            out.append((i, "return None", line))
    return out


class _Apply(ast.NodeTransformer):
    def __init__(self, target: int, nodes: dict[int, int]) -> None:
        self.target, self.nodes = target, nodes

    def visit(self, node: ast.AST) -> ast.AST:
        if self.nodes.get(id(node)) != self.target:
            return self.generic_visit(node)
        if isinstance(node, ast.Compare):
            node.ops[0] = SWAP[type(node.ops[0])]()
        elif isinstance(node, (ast.BinOp, ast.AugAssign, ast.BoolOp)):
            node.op = SWAP[type(node.op)]()
        elif isinstance(node, ast.Constant):
            node.value = (not node.value) if type(node.value) is bool else node.value + 1
        elif isinstance(node, ast.UnaryOp):
            return node.operand
        elif isinstance(node, (ast.Expr, ast.Raise)):
            return ast.Pass()
        elif isinstance(node, ast.Return):
            node.value = ast.Constant(None)
        return node


def mutated_source(source: str, index: int) -> str:
    tree = ast.parse(source)
    nodes = {id(n): i for i, n in enumerate(ast.walk(tree))}
    return ast.unparse(ast.fix_missing_locations(_Apply(index, nodes).visit(copy.copy(tree))))


def private_copy(work: Path) -> tuple[Path, Path]:
    """A copy of the repository's tests and a site dir holding the rfhoming package."""
    site = work / "site"
    pkg = site / "rfhoming"
    shutil.copytree(ROOT / "rfhoming", pkg, ignore=shutil.ignore_patterns("__pycache__"))
    for folder, name in PACKAGES.items():
        shutil.copytree(ROOT / folder, pkg / name, ignore=shutil.ignore_patterns("__pycache__"))
    repo = work / "repo"
    shutil.copytree(ROOT / "tests", repo / "tests", ignore=shutil.ignore_patterns("__pycache__"))
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, repo / name)
    shutil.copytree(ROOT / "docs", repo / "docs")
    return site, repo


def in_site(site: Path, module: str) -> Path:
    folder, _, rest = module.partition("/")
    return site / "rfhoming" / PACKAGES.get(folder, folder) / rest


def run_tests(site: Path, repo: Path, tests: list[str], timeout: float) -> str:
    env = {**os.environ, "PYTHONPATH": str(site), "PYTHONDONTWRITEBYTECODE": "1"}
    try:
        done = subprocess.run([sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", *tests],
                              cwd=repo, env=env, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return "timeout"  # a hang the tests caught by their own timeout counts as killed
    return "survived" if done.returncode == 0 else "killed"


def mutate_module(module: str, tests: list[str], max_mutants: int, seed: int, timeout: float,
                  lines: list[int] | None = None) -> dict:
    source = (ROOT / module).read_text()
    found = mutants(ast.parse(source))
    if lines:  # every mutant on these lines (re-checking survivors), no sampling
        chosen = [m for m in found if m[2] in lines]
    else:
        chosen = sorted(random.Random(f"{seed}-{module}").sample(found, min(max_mutants, len(found))), key=lambda m: m[2])
    with tempfile.TemporaryDirectory(prefix="rfhoming-mutants-") as tmp:
        site, repo = private_copy(Path(tmp))
        target = in_site(site, module)
        target.write_text(ast.unparse(ast.parse(source)))  # the baseline, as unparsed, must pass
        if run_tests(site, repo, tests, timeout) != "survived":
            raise SystemExit(f"{module}: the tests fail on the unmutated module; fix that first")
        results = []
        for index, what, line in chosen:
            target.write_text(mutated_source(source, index))
            t0 = time.monotonic()
            outcome = run_tests(site, repo, tests, timeout)
            results.append({"line": line, "mutation": what, "outcome": outcome, "s": round(time.monotonic() - t0, 1)})
            print(f"  {module}:{line} {what}: {outcome}", file=sys.stderr, flush=True)
    survived = [r for r in results if r["outcome"] == "survived"]
    return {"module": module, "tests": tests, "mutants_in_module": len(found), "mutants_run": len(results),
            "killed": len(results) - len(survived), "survived": len(survived), "survivors": survived}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--preset", choices=[*PRESETS, "all"], help="a module with its tests (all: every preset)")
    p.add_argument("--module", help="a module path in the repository, e.g. protocol/pcapng.py")
    p.add_argument("--tests", nargs="+", help="the test files that should kill its mutants")
    p.add_argument("--max", type=int, default=40, help="mutants per module, sampled with --seed (default 40)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--timeout", type=float, default=300.0, help="seconds per test run (default 300)")
    p.add_argument("--lines", type=int, nargs="+", help="instead of a sample: every mutant on these lines")
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)
    jobs = ([PRESETS[k] for k in PRESETS] if args.preset == "all" else [PRESETS[args.preset]] if args.preset
            else [(args.module, args.tests)])
    if not all(m and t for m, t in jobs):
        p.error("give --preset, or --module with --tests")
    for module, tests in jobs:
        result = mutate_module(module, tests, args.max, args.seed, args.timeout, args.lines)
        if args.json:
            print(json.dumps(result), flush=True)
        else:
            print(f"{module}: {result['mutants_run']} of {result['mutants_in_module']} mutants run, "
                  f"{result['killed']} killed, {result['survived']} survived")
            for s in result["survivors"]:
                print(f"  survived: line {s['line']}: {s['mutation']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
