"""Plots and a markdown table from bench/convergence.py JSON (runs where matplotlib is).

    python -m bench.plot_convergence bench/results/cpu/convergence.json [more.json ...]
writes beside each JSON: fig5_error_vs_h.png, fig6_error_vs_samples.png,
time_vs_error.png and convergence.md.
"""
from __future__ import annotations

import json
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

STYLE = {"riemann": ("tab:red", "o"), "trapezoid": ("tab:blue", "s"), "classified": ("tab:green", "^"),
         "split": ("tab:purple", "D")}


def _series(case, method, key):
    return [r for r in case["runs"] if r["method"] == method and (key in r)]


def plot(path):
    with open(path) as fh:
        d = json.load(fh)
    folder = os.path.dirname(path)
    title = f"{d['device_name']} ({d['device']}), {d['size'][0]}x{d['size'][1]}, {d['date']}"
    lines = [f"# Sphere convergence: {title}", "",
             f"Command: `python -m bench.convergence --device {d['device']} --size {d['size'][0]}x{d['size'][1]}`", ""]
    fig5, ax5 = plt.subplots(1, len(d["cases"]), figsize=(6 * len(d["cases"]), 4.5), squeeze=False)
    fig6, ax6 = plt.subplots(1, len(d["cases"]), figsize=(6 * len(d["cases"]), 4.5), squeeze=False)
    figt, axt = plt.subplots(1, len(d["cases"]), figsize=(6 * len(d["cases"]), 4.5), squeeze=False)
    for c, (name, case) in enumerate(d["cases"].items()):
        lines += [f"## Transfer function `{name}`", "",
                  f"Fitted orders (log max-error vs log h): " + ", ".join(
                      f"{m} {o:.2f}" if o is not None else f"{m} n/a" for m, o in case["fitted_order"].items()), "",
                  "| method | h | tolerance | max error | samples/ray | time (ms) | empty / smooth / pw segments |",
                  "|---|---|---|---|---|---|---|"]
        for r in case["runs"]:
            lines.append(f"| {r['method']} | {r.get('h', '-')} | {r.get('tolerance', '-')} | {r['max_error']:.2e} | "
                         f"{r['samples_per_ray']:.1f} | {r['seconds'] * 1e3:.2f} | "
                         f"{r['segments_empty']} / {r['segments_smooth']} / {r['segments_piecewise_smooth']} |")
        lines.append("")
        for m in ("riemann", "trapezoid", "classified"):
            rows = [r for r in case["runs"] if r["method"] == m and "tolerance" not in r]
            col, mk = STYLE[m]
            ax5[0, c].loglog([r["h"] for r in rows], [r["max_error"] for r in rows], marker=mk, color=col,
                             label=f"{m} (order {case['fitted_order'][m]:.2f})" if case["fitted_order"][m] else m)
        for m in ("riemann", "trapezoid", "classified", "split"):
            rows = [r for r in case["runs"] if r["method"] == m]
            rows.sort(key=lambda r: r["samples_per_ray"])
            col, mk = STYLE[m]
            ax6[0, c].loglog([r["samples_per_ray"] for r in rows], [r["max_error"] for r in rows], marker=mk, color=col,
                             ls="", label=m)
            rows.sort(key=lambda r: r["seconds"])
            axt[0, c].loglog([r["seconds"] for r in rows], [r["max_error"] for r in rows], marker=mk, color=col, ls="",
                             label=m)
        for ax, xl in ((ax5[0, c], "step h (world units)"), (ax6[0, c], "samples per ray (field + restriction)"),
                       (axt[0, c], "wall time per image (s)")):
            ax.axhline(1e-3, color="gray", ls="--", lw=0.8)
            ax.set_xlabel(xl)
            ax.set_ylabel("max |RGB - reference|")
            ax.set_title(f"sphere, TF '{name}'")
            ax.grid(True, which="both", alpha=0.3)
            ax.legend(fontsize=8)
    for fig, fname in ((fig5, "fig5_error_vs_h.png"), (fig6, "fig6_error_vs_samples.png"), (figt, "time_vs_error.png")):
        fig.suptitle(title, fontsize=9)
        fig.tight_layout()
        fig.savefig(os.path.join(folder, fname), dpi=110)
        plt.close(fig)
    with open(os.path.join(folder, "convergence.md"), "w") as fh:
        fh.write("\n".join(lines) + "\n")
    print("plotted", folder)


if __name__ == "__main__":
    for p in sys.argv[1:]:
        plot(p)
