"""Numpydoc coverage of public functions (issue 23: fitting/ and diagnosis/ >= 90 %).

    python benchmarks/doc_coverage.py accelcal/fitting accelcal/diagnosis [--list]

A public function or method counts as documented when its docstring has a ``Parameters``
section (if it takes arguments besides self/cls) and a ``Returns`` or ``Yields`` section (if
annotated to return something other than None); a property needs a docstring.  Prints
documented/total and, with --list, the ones that are not.
"""
from __future__ import annotations

import ast
import pathlib
import sys


def audit(roots: list[str]) -> tuple[int, int, list[str]]:
    total = ok = 0
    bad: list[str] = []

    def visit(node, f, cls=None):
        nonlocal total, ok
        for n in ast.iter_child_nodes(node):
            if isinstance(n, ast.ClassDef) and not n.name.startswith("_"):
                visit(n, f, n.name)
            elif isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)) and not n.name.startswith("_"):
                total += 1
                doc = ast.get_docstring(n) or ""
                deco = [getattr(d, "id", getattr(d, "attr", "")) for d in n.decorator_list]
                args = [a.arg for a in n.args.args + n.args.kwonlyargs if a.arg not in ("self", "cls")]
                rets = n.returns is not None and not (isinstance(n.returns, ast.Constant) and n.returns.value is None)
                good = bool(doc) if "property" in deco else (
                    bool(doc) and (not args or "Parameters\n" in doc)
                    and (not rets or "Returns\n" in doc or "Yields\n" in doc))
                ok += good
                if not good:
                    bad.append(f"{f}:{n.lineno} {cls + '.' if cls else ''}{n.name}")

    for root in roots:
        for f in sorted(pathlib.Path(root).glob("*.py")):
            visit(ast.parse(f.read_text(encoding="utf-8")), f)
    return ok, total, bad


if __name__ == "__main__":
    roots = [a for a in sys.argv[1:] if not a.startswith("--")] or ["accelcal/fitting", "accelcal/diagnosis"]
    ok, total, bad = audit(roots)
    print(f"{ok}/{total} = {100 * ok / max(total, 1):.0f} % documented in numpydoc ({', '.join(roots)})")
    if "--list" in sys.argv:
        print("\n".join(bad))
