"""CLI of ``accelcal design RUNS...``: which run to add, and what it will buy
(:mod:`accelcal.testdesign`).  Registration is cheap; the science is imported when the
command runs."""
from __future__ import annotations


def register(sub) -> None:
    """Add ``design``."""
    d = sub.add_parser(
        "design", help="which run to add to a campaign, and what it will buy",
        description="From the campaign model's Fisher information: the runs the rigs of "
                    "RUNS can make (other mount angles every 45 deg, planes, vertical axes, "
                    "tumble heads, thermal set-points, repeats), ranked by the reduction of "
                    "each target's variance (or of a pair's correlation) per minute of rig "
                    "time. Every instrument coefficient is treated as unknown.")
    d.add_argument("paths", nargs="+", metavar="RUNS", help="run files or folders, as for diagnose")
    d.add_argument("--baseline", default=None,
                   help="effects the model includes (comma-separated effects.md ids), or 'none'; "
                        "default: the pipeline's own processing")
    d.add_argument("--target", default=None, metavar="NAME[,NAME...]",
                   help="coefficients (Kip, K2, ...) or effect ids (an effect the baseline leaves "
                        "out: the advice is about seeing it); default every instrument coefficient")
    d.add_argument("--separate", action="append", default=[], metavar="A,B",
                   help="a pair whose correlation should fall below 0.9 (repeatable)")
    d.add_argument("--max-runs", type=int, default=2, metavar="K", help="largest set of runs proposed (default 2)")
    d.add_argument("--candidates", default=None, metavar="FILE.toml",
                   help="the lab's own candidate runs ([[run]] tables in drop-format keys)")
    d.add_argument("--config", default=None, metavar="TOML",
                   help="accelcal.toml with [rigs.\"ID\"] max_g, setup_min and the stated rig-input "
                        "uncertainties the budget adds (default ./accelcal.toml)")
    d.add_argument("--top", type=int, default=5, metavar="N", help="proposals shown (default 5)")
    d.add_argument("--json", action="store_true", help="one JSON object on stdout")
    d.set_defaults(func=_cmd_design)


def _fail(msg: str):
    from ..cli import CliError
    raise CliError(msg)


def _cmd_design(args) -> int:
    import json

    from ..config import ConfigError, advice_inputs, rig_limits
    from ..diagnosis.core import prepare_cells, resolve_baseline
    from ..diagnosis.runfiles import read_paths
    from ..testdesign import DesignError, advise, load_candidates
    runs = read_paths(args.paths)
    if not runs:
        _fail("no run file could be read from " + ", ".join(args.paths))
    tests = sorted({str(r.meta["test"]) for r in runs})
    try:
        baseline, _ = resolve_baseline(args.baseline, tests)
    except ValueError as exc:
        _fail(str(exc))
    pairs = []
    for s in args.separate:
        ab = [x.strip() for x in s.split(",") if x.strip()]
        if len(ab) != 2:
            _fail(f"--separate {s!r}: give two names, A,B")
        pairs.append((ab[0], ab[1]))
    targets = [t.strip() for t in (args.target or "").split(",") if t.strip()]
    if args.max_runs < 1:
        _fail("--max-runs must be 1 or more")
    cells, _ = prepare_cells(runs)
    try:
        cands = (load_candidates(args.candidates, cells, rig_limits(args.config))
                 if args.candidates else None)
        adv = advise(cells, baseline, targets or None, pairs, args.max_runs, cands, args.top,
                     **advice_inputs(args.config))
    except (DesignError, ConfigError) as exc:
        _fail(str(exc))
    if args.json:
        print(json.dumps(adv.to_dict()))
    else:
        units = {str(r.meta.get("output_unit")) for r in runs if r.meta.get("output_unit")}
        print(text_advice(adv, units.pop() if len(units) == 1 else "out"))
    return 0


#: A standard uncertainty this many times the catalogue's typical size of the parameter
#: (accelcal/effects.py) says the runs do not determine it [1].
UNDETERMINED_TYPICAL = 1e3


def _u(name: str, u: float | None, unit: str, output_unit: str = "out", value: float | None = None) -> str:
    """A standard uncertainty for people: 2 significant digits in the display unit, the
    runs' output unit for "out"; K1's relative, in ppm of its current ``value`` as the
    certificate gives it; "not determined" for none, or one far above the parameter's
    typical size."""
    import math

    from ..effects import EFFECTS, coefficient_spec, to_display
    from ..rounding import format_sig, format_sig_sci
    base = name.split("[", 1)[0]
    spec = coefficient_spec(base) or EFFECTS.get(base)
    if u is None or not math.isfinite(u) or (spec is not None and spec.typical
                                             and u > UNDETERMINED_TYPICAL * spec.typical):
        return "not determined"
    if base == "K1" and value:
        return f"{format_sig(u / abs(value) * 1e6, 2)} ppm"
    if unit.startswith("out/"):
        unit = output_unit + unit[3:]
    v, _, dunit, _ = to_display(base, u, None, unit)
    text = format_sig(v, 2) if 1e-3 <= abs(v) < 1e5 else format_sig_sci(v, 2)
    return f"{text} {dunit}".strip()


def _seen(name: str, u: float | None, plausible: float | None) -> str:
    """For an effect target: how many u its plausible size is (how clearly it would show)."""
    from ..effects import EFFECTS
    if u is None or not plausible or name.split("[", 1)[0] not in EFFECTS:
        return ""
    return f" (plausible size {plausible / u:.0f} u)"


def text_advice(adv, output_unit: str = "out") -> str:
    """The advice as a short table an engineer reads in ten seconds (80 columns); every
    u in its display unit, "out" read as the runs' ``output_unit``."""
    lines = []
    names = list(adv.current.std_uncertainty)
    cur = "; ".join(f"u({n}) {_u(n, adv.current.std_uncertainty[n], adv.units.get(n, ''), output_unit, adv.values.get(n))}"
                    f"{_seen(n, adv.current.std_uncertainty[n], adv.plausible.get(n))}" for n in names)
    lines.append(f"Now: {cur}")
    for k, r in adv.current.corr.items():
        lines.append(f"     corr({k.replace('|', ', ')}) " + ("not determined" if r is None else f"{r:.2f}"))
    lines.append(f"{adv.candidates} candidate runs; best per minute of rig time:")
    if not adv.proposals:
        lines.append("  none improves the targets")
    for i, p in enumerate(adv.proposals, 1):
        lines.append(f"{i:>2}. {p.minutes:.0f} min: " + " + ".join(c.label for c in p.runs))
        got = "; ".join(f"u({n}) {_u(n, p.predicted.std_uncertainty.get(n), adv.units.get(n, ''), output_unit, adv.values.get(n))}"
                        f"{_seen(n, p.predicted.std_uncertainty.get(n), adv.plausible.get(n))}" for n in names)
        corr = "; ".join(f"corr {('not determined' if r is None else f'{r:.2f}')}"
                         for k, r in p.predicted.corr.items())
        lines.append("    -> " + got + (f"; {corr}" if corr else ""))
    for n in adv.notes:
        lines.append(f"note: {n}")
    lines += _assumptions(adv, output_unit)
    import textwrap
    out = []
    for ln in lines:
        out += textwrap.wrap(ln, 80, subsequent_indent="       ") or [""]
    return "\n".join(out)


def _assumptions(adv, output_unit: str) -> list[str]:
    """What every prediction rests on: the noise model fitted to the runs, the set-up time
    counted per run, the type-B terms of the pipeline's budget."""
    from ..rounding import format_sig, format_sig_sci
    out = []
    for nm in adv.noise:
        unit = nm["output_unit"] if nm["output_unit"] != "out" else output_unit
        runs = f"{nm['runs']} run" + ("s" if nm["runs"] != 1 else "")
        line = (f"noise: {nm['rig_id']} {nm['test']} ({runs}, fitted to the residuals): "
                f"{format_sig_sci(nm['sigma'], 2)} {unit}"
                + (f" ({format_sig(nm['sigma_ug'], 2)} µg)" if "sigma_ug" in nm else "") + " per reading")
        if nm["rate_sigma_per_m_s2"] > 0:
            line += (f" plus rate jitter {format_sig_sci(nm['rate_sigma_per_m_s2'], 2)} {unit} per m/s² "
                     "of level, seen through IA's share of the radius")
        if nm["rho"]:
            line += f"; lag-1 correlation {nm['rho']:.2f}"
        out.append(line)
    for rig, m in sorted(adv.setup_min.items()):
        src = "stated" if rig in adv.setup_stated else f'default; state [rigs."{rig}"] setup_min'
        out.append(f"set-up: {m:g} min per run on {rig} ({src})")
    out.append("u: type A of the joint fit plus the type-B terms its budget adds (mount angles, "
               "IA tilt, stated rig inputs)")
    return out
