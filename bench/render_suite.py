#!/usr/bin/env python3
"""Renders rest / ARAP / scale-aware results of the Table 1 suite to one PNG (the README picture).

Optional tool, not part of the build: needs Debian's python3-matplotlib (run with /usr/bin/python3).
Usage: bench/render_suite.py BUILD_DIR OUT.png [model ...]   (default models: cylinder bar cactus)
It generates the suite with meshdeform-cli, deforms each model with both methods, and draws them.
"""
import os
import subprocess
import sys
import tempfile

import matplotlib
matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from mpl_toolkits.mplot3d.art3d import Poly3DCollection  # noqa: E402


def load_obj(path):
    V, F = [], []
    for line in open(path):
        t = line.split()
        if t and t[0] == "v":
            V.append([float(x) for x in t[1:4]])
        elif t and t[0] == "f":
            F.append([int(x.split("/")[0]) - 1 for x in t[1:4]])
    return np.array(V), np.array(F)


def load_off(path):
    lines = [l for l in open(path) if l.strip() and not l.startswith("#")]
    n, f, _ = map(int, lines[1].split())
    V = np.array([[float(x) for x in l.split()[:3]] for l in lines[2:2 + n]])
    F = np.array([[int(x) for x in l.split()[1:4]] for l in lines[2 + n:2 + n + f]])
    return V, F


def draw(ax, V, F, title):
    tri = V[F]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.linalg.norm(n, axis=1)[:, None] + 1e-12
    light = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    shade = 0.3 + 0.7 * np.clip(n @ light, 0, 1)
    ax.add_collection3d(Poly3DCollection(tri, facecolors=plt.cm.Greys(0.2 + 0.6 * shade),
                                         edgecolor="none"))
    c, r = V.mean(0), (V.max(0) - V.min(0)).max() / 2
    ax.set_xlim(c[0] - r, c[0] + r)
    ax.set_ylim(c[1] - r, c[1] + r)
    ax.set_zlim(c[2] - r, c[2] + r)
    ax.set_title(title)
    ax.axis("off")
    ax.view_init(15, -60)


def main():
    build, out = sys.argv[1], sys.argv[2]
    models = sys.argv[3:] or ["cylinder", "bar", "cactus"]
    cli = os.path.join(build, "cli", "meshdeform-cli")
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run([cli, "generate", "--model", "all", "--out-dir", tmp], check=True,
                       stdout=subprocess.DEVNULL)
        fig = plt.figure(figsize=(12, 4 * len(models)))
        k = 1
        for m in models:
            base = os.path.join(tmp, m)
            panels = [("rest", load_off(base + ".off"))]
            for method in ("arap", "scale_aware"):
                result = f"{base}_{method}.obj"
                subprocess.run([cli, "deform", "--mesh", base + ".off", "--sel", base + ".sel",
                                "--def", base + ".def", "--out", result, "--method", method],
                               check=True, stdout=subprocess.DEVNULL)
                panels.append((method.replace("_", "-"), load_obj(result)))
            for title, (V, F) in panels:
                draw(fig.add_subplot(len(models), 3, k, projection="3d"), V, F, f"{m}: {title}")
                k += 1
        plt.tight_layout()
        plt.savefig(out, dpi=55)


if __name__ == "__main__":
    main()
