"""Write docs/mutation-report.md from the last ``mutmut run``: every surviving mutant with the reason it is left.

    mutmut run --max-children 2            # see tests/README.md
    python docs/make_mutation_report.py     # from the project root

Each survivor gets the first reason below whose rule matches its diff; a survivor no rule explains is listed
under "not yet reviewed" with its diff, so the report never hides one. The rules were written after reading the
survivors one by one; each names why the mutant is equivalent or not worth a test.
"""

from __future__ import annotations

import json
import re
import sys
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
STRING = re.compile(r'f?"(?:[^"\\]|\\.)*"|f?\'(?:[^\'\\]|\\.)*\'')


@dataclass(frozen=True)
class Mutant:
    name: str  # module.x_function__mutmut_N
    minus: tuple[str, ...]  # the original lines the mutant changes, stripped
    plus: tuple[str, ...]  # the mutated lines, stripped

    @property
    def function(self) -> str:
        return re.sub(r"__mutmut_\d+$", "", self.name)

    @property
    def old(self) -> str:
        return " ".join(self.minus)

    @property
    def new(self) -> str:
        return " ".join(self.plus)


def _flying_half() -> set[str]:
    """The lines of ``run`` that only a flight executes (from ``if not plan_only:`` to the plan-only start)."""
    text = (ROOT / "skyroute" / "cli" / "main.py").read_text()
    block = text[text.index("    if not plan_only:\n"):text.index("    start_ne = (0.0, 0.0)\n")]
    return {line.strip() for line in block.splitlines() if line.strip()}


FLYING_HALF = _flying_half()


def only_strings_differ(m: Mutant) -> bool:
    return STRING.sub("S", m.old) == STRING.sub("S", m.new)


def reworded(m: Mutant) -> bool:
    """Strings only, each re-cased or wrapped in XX (what mutmut does to text)."""
    if not only_strings_differ(m):
        return False
    pairs = zip(STRING.findall(m.old), STRING.findall(m.new))
    return all(b in (a, a.upper(), a.lower()) or b.replace("XX", "") == a for a, b in pairs)


def help_display(m: Mutant) -> bool:
    return m.function.endswith("x_build_parser") and (
        reworded(m) or bool(re.search(r"\b(help|metavar|description|prog)=None\b", m.new))
        or "add_argument_group" in m.old
        or (m.old.replace(" ", "").count("help=") == 1 and "help=" not in m.new.replace(" ", ""))
        or bool(re.search(r'\bmetavar="[^"]*"', m.old) and not re.search(r'\bmetavar=', m.new))
        or "formatter_class" in m.old
    )


def any_of(*patterns: str):
    return lambda m: any(re.search(p, m.old) for p in patterns)


REASONS: list[tuple[str, str, object]] = [
    ("flying", "The flying half of `run()` (connect, log, fly, the bundled sim): only flights execute it, and the "
     "flight tests are outside this fast selection. Left for the flight side, with `skyroute/cli/flying.py`.",
     lambda m: m.function.endswith("cli.main.x_run") and all(line in FLYING_HALF for line in m.minus)),
    ("help", "`--help` text and layout (wording, metavars, group titles, the program name): not behaviour; "
     "`test_help_shows_defaults` checks the help shows the defaults, README's table is checked against the parser.",
     help_display),
    ("dest", "Equivalent: argparse derives the same `dest` from the option's long name (`--arm-timeout` -> "
     "`arm_timeout`).", lambda m: m.function.endswith("x_build_parser") and "dest=None" in m.new),
    ("wording", "Message wording: the mutant re-cases a message or wraps it in `XX`; the tests check the fragment "
     "that carries the meaning (the option, the number, the place), not every letter.", reworded),
    ("dtype", "Equivalent: a `dtype` dropped or `None` where the array already has that type (maps and grids are "
     "float64 and bool throughout; the compiled kernels would refuse anything else at their first call).",
     lambda m: bool(re.search(r"dtype=np\.\w+|np\.(bool_|int64|float64)\)", m.old))
     and bool(re.search(r"dtype=None|\(\s*\)|, \)|None\)", m.new)) and "loadtxt" not in m.old),
    ("window", "Equivalent: the nearest-free-cell searches look in square windows of doubling size; the first "
     "size, the growth and the stopping test (`<` or `<=` the window's reach) change how many cells are looked "
     "at, not which distance is found (brute-force tests on random, non-square maps check the answer).",
     lambda m: m.function.split(".")[-1] in ("x_nearest_free_cell", "x_nearest_free_in_map", "x_snap_start_cell")
     and bool(re.search(r"\bhalf\b|i0|j0|i1|j1|whole_grid|kind=", m.old))),
    ("fastpath", "Equivalent: the NumPy fast path of the map reader; when it fails or is skipped the line-by-line "
     "reader parses the same rows (`test_fast_and_line_by_line_readers_agree`); only speed differs.",
     lambda m: m.function.endswith("maps.x__parse_rows") and ("loadtxt" in m.old or "obstacles" in m.old)),
    ("timing", "A duration (`search_ms`, `build_ms`): measured, never asserted (timing is for `bench/`).",
     any_of(r"perf_counter", r"search_ms", r"build_ms")),
    ("rounding", "Display precision of the summary and the JSON (3 and 4 decimals, i.e. 1 mm or 0.1 mm): not "
     "asserted, not worth a test.", lambda m: bool(re.search(r"round\(", m.old))),
    ("warmup", "Equivalent: `_load` compiles the kernels on a tiny grid; which tiny grid does not matter.",
     lambda m: m.function.endswith("search.x__load")),
    ("stdout", "Equivalent through the command line: `print_plan` and the compile notice write to the stream "
     "given, which the CLI sets to `sys.stdout`/`sys.stderr` anyway (the default `print` target); `flush` on "
     "stderr, which is line-buffered, changes nothing; `main` always passes `enabled`.",
     lambda m: m.function.split(".")[-1] in ("x_print_plan", "x_announce_first_compile")
     and not re.search(r"print\(\s*(None|file=)", m.new.replace("print(plan_summary", "x"))),
    ("picture", "What the `--plot` picture shows (which height map is drawn under a 3D route): the test checks a "
     "PNG is written; the figure's content is checked by eye in `docs/` (not worth a pixel test).",
     lambda m: m.function.endswith("cli.setting.x_save_plot")),
    ("logging", "Log format and level: a plan-only run logs nothing at INFO (the verbose log is the flight's), so "
     "`-v` changes nothing here; the flight tests read it.",
     lambda m: m.function.endswith("cli.main.x_main") and ("format=" in m.old or "logging.INFO" in m.old)),
    ("subprocess", "Covered by a test mutmut cannot attribute: `test_a_reader_that_leaves_early_gets_exit_1_and_no_"
     "traceback` runs the command line in a child process (a closed pipe cannot be faked in-process without "
     "redirecting pytest's own stdout), and mutmut only runs the tests it saw call the function in its process.",
     lambda m: m.function.endswith("cli.main.x_main") and ("dup2" in m.old or "devnull" in m.old)),
    ("altitude0", "Equivalent to far below the tests' 1 cm: the altitude (0 m -> 1 m) of a point or home used only "
     "for its latitude and longitude or its north and east (a metre of height moves them by ~1e-7 m).",
     lambda m: bool(re.search(r"(Geodetic|LocalNED)\(.*0\.0\)", m.old)) and bool(re.search(r"1\.0\)|, \)", m.new))),
    ("prm-message", "Unreachable: `make_plan`'s PRM messages. The PRM falls back to the complete grid3d search, "
     "which always finds a route (it can climb over everything), so no `NoPathError` comes out of `prm`.",
     lambda m: m.function.endswith("cli.setting.x_make_plan") and bool(re.search(r'prm|why', m.old))),
    ("falsy", "Equivalent: `None` for a flag that is only tested for truth (`snap_start`, `allow_margin`, "
     "`on_map_only`), or for a keyword whose default is the same.",
     lambda m: bool(re.search(r"(snap_start|allow_margin|on_map_only)=None", m.new))
     or bool(re.search(r"(snap_start=snap_start|allow_margin=snap_start)", m.old)
             and not re.search(r"(snap_start|allow_margin)=", m.new))),
    ("buffer", "Equivalent: the size of the supercover's scratch buffer (a larger one is trimmed to the walk's "
     "count) or of the one-cell grid the walk ignores when it records cells.",
     lambda m: m.function.endswith("pruning.x_supercover") and ("np.empty" in m.old or "np.zeros" in m.old)),
    ("repeat", "Equivalent on planner output: `_max_offset`'s guard for a zero-length chord; pruned paths never "
     "repeat a point, so the chord is never zero.", lambda m: m.function.endswith("pruning.x__max_offset")),
    ("flat3d", "Equivalent for a flat route: the grid planner's waypoints share one altitude, so including it in "
     "the length or the headings changes nothing.", lambda m: ":, :3]" in m.new and ":, :2]" in m.old),
]


def load_survivors(mutants_dir: Path) -> list[Mutant]:
    import mutmut.__main__  # noqa: F401  (loads the configuration)
    from mutmut.mutation.diff_apply import find_mutant, get_diff_for_mutant

    survivors = []
    for meta in sorted(mutants_dir.rglob("*.py.meta")):
        codes = json.loads(meta.read_text())["exit_code_by_key"]
        for name in sorted(k for k, v in codes.items() if v == 0):
            diff = get_diff_for_mutant(name, path=find_mutant(name).path).splitlines()
            minus = tuple(x[1:].strip() for x in diff if x.startswith("-") and not x.startswith("---"))
            plus = tuple(x[1:].strip() for x in diff if x.startswith("+") and not x.startswith("+++"))
            survivors.append(Mutant(name, minus, plus))
    return survivors


def totals(mutants_dir: Path) -> tuple[int, dict[str, int]]:
    from mutmut.stats import status_by_exit_code

    count, by_status = 0, defaultdict(int)
    for meta in mutants_dir.rglob("*.py.meta"):
        for code in json.loads(meta.read_text())["exit_code_by_key"].values():
            count += 1
            by_status[status_by_exit_code[code]] += 1
    return count, dict(by_status)


def numbers(names: list[str]) -> str:
    return ", ".join(name.rsplit("_", 1)[1] for name in sorted(names, key=lambda n: int(n.rsplit("_", 1)[1])))


def main() -> int:
    mutants_dir = ROOT / "mutants"
    if not mutants_dir.is_dir():
        print("error: no mutants/ here; run `mutmut run` first (tests/README.md)", file=sys.stderr)
        return 1
    survivors = load_survivors(mutants_dir)
    count, by_status = totals(mutants_dir)
    grouped: dict[str, list[Mutant]] = defaultdict(list)
    for m in survivors:
        key = next((key for key, _, rule in REASONS if rule(m)), "unreviewed")
        grouped[key].append(m)
    lines = [
        "# Mutation testing: the surviving mutants and why they are left",
        "",
        "Generated by `python docs/make_mutation_report.py` from the last `mutmut run` (configuration: pyproject's",
        "`[tool.mutmut]`; command: `tests/README.md`). Mutant names are `module.x_function__mutmut_N`;",
        "`mutmut show NAME` prints one's diff.",
        "",
        f"**{count} mutants**: " + ", ".join(f"{n} {status}" for status, n in sorted(by_status.items())) + ".",
        "",
    ]
    for key, reason, _ in [*REASONS, ("unreviewed", "Not yet reviewed (each listed with its diff).", None)]:
        members = grouped.get(key, [])
        if not members:
            continue
        lines += [f"## {len(members)} {key}", "", reason, ""]
        by_function: dict[str, list[str]] = defaultdict(list)
        for m in members:
            by_function[m.function].append(m.name)
        for function, names in sorted(by_function.items()):
            lines.append(f"- `{function}`: {numbers(names)}")
            if key == "unreviewed":
                for name in names:
                    m = next(x for x in members if x.name == name)
                    lines.append(f"  - {name.rsplit('_', 1)[1]}: `{m.old[:150]}` -> `{m.new[:150]}`")
        lines.append("")
    (ROOT / "docs" / "mutation-report.md").write_text("\n".join(lines))
    print(f"{len(survivors)} survivors, {len(grouped.get('unreviewed', []))} not yet reviewed")
    return 0


if __name__ == "__main__":
    sys.exit(main())
