#!/usr/bin/env python3
"""The paper's hammer grasp (by the handle) at the table, statically: on which of
the database's 4 hammers does a pinch across the handle from above reach force
closure? (docs/results.md, "Cross-category, hammers to knives").

Runs `cell quality --object db/hammer/models/hammer_00K.ply --pose P --table-z 0
--spread S --preshape-rad A --approach-to-contact --json` on a 1,248-point grid per
hammer: the palm from above (roll pi) over the handle at x = -0.05..0.09 m (the
head is at the -x end, near -0.08), yaw 0 or pi (F3 on one side of the handle, F1
and F2 on the other), lateral offset -4, 0, 4 mm, spread 0 or 0.2 rad, pre-shape
1.15..1.45 rad in 0.025 steps. Prints, per hammer, the grid points with epsilon > 0
and the best five. About 35 s on 2 cores (two hammers at a time).

usage: python3 docs/hammer_handle_pinch_grid.py [CELL]   (default target/release/cell)
"""
import itertools, json, subprocess, sys
from concurrent.futures import ThreadPoolExecutor

CELL = sys.argv[1] if len(sys.argv) > 1 else 'target/release/cell'
XS = [-0.05 + 0.02 * i for i in range(8)]
PRESHAPES = [1.15 + 0.025 * i for i in range(13)]
YAWS = [0.0, 3.14159]
LATERAL = [-0.004, 0.0, 0.004]
SPREADS = [0.0, 0.2]


def epsilon(mesh, x, y, yaw, spread, preshape):
    cmd = [CELL, 'quality', '--object', mesh, '--pose=%.3f,%.3f,0.173,3.14159,0,%s' % (x, y, yaw),
           '--spread', str(spread), '--preshape-rad', '%.3f' % preshape,
           '--table-z', '0', '--approach-to-contact', '--json']
    out = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout
    return json.loads(out)['epsilon']


def grid(k):
    mesh = 'db/hammer/models/hammer_%03d.ply' % k
    closed = []
    points = list(itertools.product(XS, PRESHAPES, YAWS, LATERAL, SPREADS))
    for x, p, yaw, y, s in points:
        e = epsilon(mesh, x, y, yaw, s, p)
        if e > 0:
            closed.append((round(e, 4), round(x, 3), round(p, 3), yaw, y, s))
    return {'hammer': mesh, 'tests': len(points), 'force_closure': len(closed),
            'best (epsilon, x, preshape, yaw, lateral, spread)': sorted(closed)[-5:]}


with ThreadPoolExecutor(2) as pool:
    for row in pool.map(grid, range(4)):
        print(json.dumps(row))
