"""Print constraints.txt with each runtime dependency (setup.py's INSTALL_REQUIRES) pinned at its lower
bound instead: what CI's second leg installs, so that the low ends of the ranges are tested.

    python3 .ci/lower_bounds.py > /tmp/lowest.txt && pip install -c /tmp/lowest.txt -e ".[test,ros]"

Every INSTALL_REQUIRES entry must have a ``>=`` bound (the script fails naming one that has none).
"""
import ast
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
NAME = re.compile(r"^\s*([A-Za-z0-9][A-Za-z0-9._-]*)")


def canonical(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def install_requires() -> list[str]:
    tree = ast.parse((ROOT / "setup.py").read_text())
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == "INSTALL_REQUIRES" for t in node.targets):
            return ast.literal_eval(node.value)
    raise SystemExit("setup.py: no INSTALL_REQUIRES list")


def main() -> None:
    lowest = {}
    for requirement in install_requires():
        name = NAME.match(requirement).group(1)
        bound = re.search(r">=\s*([^,;\s]+)", requirement)
        if bound is None:
            raise SystemExit(f"setup.py: {requirement!r} has no lower bound (>=)")
        lowest[canonical(name)] = f"{name}=={bound.group(1)}"
    out = []
    for line in (ROOT / "constraints.txt").read_text().splitlines():
        match = NAME.match(line)
        key = canonical(match.group(1)) if match and not line.lstrip().startswith("#") else None
        out.append(lowest.pop(key) + "  # lower bound (setup.py)" if key in lowest else line)
    if lowest:
        raise SystemExit(f"constraints.txt pins none of {sorted(lowest)}")
    sys.stdout.write("\n".join(out) + "\n")


if __name__ == "__main__":
    main()
