"""The package's size as the house measures it: lines of code (no blank lines, comments or
docstrings, counted with ``ast`` and ``tokenize``) and every function over 60 lines.

Usage: ``python benchmarks/code_size.py [PATH]`` (default ``nutribench``; a folder or one file).
"""

import ast
import io
import sys
import tokenize
from pathlib import Path

SKIPPED = {tokenize.COMMENT, tokenize.NL, tokenize.NEWLINE, tokenize.INDENT, tokenize.DEDENT, tokenize.ENDMARKER}
DOCUMENTED = (ast.Module, ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)


def docstring_lines(tree: ast.AST) -> set[int]:
    """The line numbers of every module, class and function docstring in ``tree``."""
    lines: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, DOCUMENTED) and node.body:
            first = node.body[0]
            if (
                isinstance(first, ast.Expr)
                and isinstance(first.value, ast.Constant)
                and isinstance(first.value.value, str)
            ):
                lines.update(range(first.lineno, first.end_lineno + 1))
    return lines


def measure(root: Path) -> tuple[int, list[tuple[int, str]]]:
    """Code lines under ``root`` and the functions over 60 lines, as (length, place)."""
    total, long = 0, []
    for path in [root] if root.is_file() else sorted(root.rglob("*.py")):
        source = path.read_text()
        tree = ast.parse(source)
        docs = docstring_lines(tree)
        code = set()
        for tok in tokenize.generate_tokens(io.StringIO(source).readline):
            if tok.type not in SKIPPED:
                code.update(line for line in range(tok.start[0], tok.end[0] + 1) if line not in docs)
        total += len(code)
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.end_lineno - node.lineno + 1 > 60:
                long.append((node.end_lineno - node.lineno + 1, f"{path}:{node.lineno} {node.name}"))
    return total, sorted(long, reverse=True)


if __name__ == "__main__":
    total, long = measure(Path(sys.argv[1] if len(sys.argv) > 1 else "nutribench"))
    print(f"code lines {total}, functions over 60 lines {len(long)}")
    for length, place in long:
        print(length, place)
