#!/usr/bin/env python3
"""Which hammers can the BH8-282 lift off the table at all? An exhaustive grid of
grasps, each closed with approach to contact and judged by the physics lift test
(the observer's physics: close, lift 0.10 m, hold 2 s), on the object's true mesh
in its own frame with the table at z = 0 (docs/results.md, "Which hammers can be
lifted at all").

The hammers of `cell eval novel` (held-apart family, set 1, 10 instances: the
objects of its hammer rows; a placement only turns and moves a hammer on the table,
which the lift does not depend on) and the 4 database hammers (training family,
seed 1: db/hammer/models). Every grasp is the palm from above (roll pi), as the
cell plans them, in four families:

- head-across (180): the palm over the head's centre +-8 mm along the handle, the
  fingers closing across the head (yaw -pi/2: F1 and F2 on the handle's side,
  either side of the handle; yaw +pi/2: F3 there), pre-shape 0.8..1.2 rad, spread
  0.2/0.35/0.5;
- head-along (144): the fingers closing along the head (face to peen), yaw 0 or
  pi, +-6 mm across and +-10 mm along, pre-shape 0.7..1.1 rad, spread 0 or 0.2;
- handle-across (128): at 15/35/55/75 % of the handle from the head, +-4 mm
  across, yaw 0 or pi, pre-shape 0.85..1.0 rad, spread 0 or 0.3;
- head-tilted (84): head-across (yaw -pi/2, spread 0.35) with the palm tilted by
  up to 0.06 rad about the head's axis and 0.03 rad about the handle's (14 tilts),
  +-4 mm, pre-shape 0.95 or 1.1 rad.

Prints one JSON line per hammer: its head section, the lifts (success) and
partials per family, and some of the grasps that lift it. About 2.5 min per hammer on 2 cores (536
lifts); name hammers to survey only those.

usage: python3 docs/hammer_lift_grid.py [--cell CELL] [HAMMER ...]
       (default target/release/cell; HAMMER as hammer-novel-1-3.obj, hammer_001.obj)
"""
import itertools, json, math, os, subprocess, sys, tempfile
from concurrent.futures import ThreadPoolExecutor

ARGS = sys.argv[1:]
CELL = 'target/release/cell'
if ARGS[:1] == ['--cell']:
    CELL, ARGS = ARGS[1], ARGS[2:]
PI = math.pi


def generate(out, family, seed, count):
    subprocess.run([CELL, 'objects', 'generate', '--category', 'hammer', '--family', family,
                    '--seed', str(seed), '--count', str(count), '--out', out],
                   capture_output=True, check=True)
    return json.load(open(os.path.join(out, 'params.json')))['instances']


def grasps(instance):
    """(family, x, y, roll, pitch, yaw, preshape, spread) in the hammer's frame."""
    p = instance['params']
    s, handle = p['head_section_m'], p['handle_length_m']
    head_x = instance['bounding_box_m'][0][0] + s / 2.0
    for dx, yaw, pre, spr in itertools.product([-0.008, -0.004, 0, 0.004, 0.008], [-PI / 2, PI / 2],
                                               [0.8, 0.9, 0.95, 1.0, 1.1, 1.2], [0.2, 0.35, 0.5]):
        yield ('head-across', head_x + dx, 0.0, PI, 0.0, yaw, pre, spr)
    for dx, dy, yaw, pre, spr in itertools.product([-0.006, 0, 0.006], [-0.01, 0, 0.01], [0, PI],
                                                   [0.7, 0.9, 1.0, 1.1], [0.0, 0.2]):
        yield ('head-along', head_x + dx, dy, PI, 0.0, yaw, pre, spr)
    for f, dy, yaw, pre, spr in itertools.product([0.15, 0.35, 0.55, 0.75], [-0.004, 0.004], [0, PI],
                                                  [0.85, 0.9, 0.95, 1.0], [0.0, 0.3]):
        yield ('handle-across', head_x + s / 2.0 + f * handle, dy, PI, 0.0, yaw, pre, spr)
    tilts = [(r, q) for r in (-0.06, -0.03, 0, 0.03, 0.06) for q in (-0.03, 0, 0.03) if (r, q) != (0, 0)]
    for dx, (dr, dp), pre in itertools.product([-0.004, 0, 0.004], tilts, [0.95, 1.1]):
        yield ('head-tilted', head_x + dx, 0.0, PI + dr, dp, -PI / 2, pre, 0.35)


def lift(mesh, g):
    _, x, y, roll, pitch, yaw, pre, spr = g
    cmd = [CELL, 'quality', '--object', mesh, '--pose=%.4f,%.4f,0.20,%.4f,%.4f,%.4f' % (x, y, roll, pitch, yaw),
           '--spread', str(spr), '--preshape-rad', str(pre), '--table-z', '0',
           '--approach-to-contact', '--lift', '--json']
    out = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout
    return json.loads(out)['lift']['grade']


def survey(mesh, instance, origin):
    counts, best = {}, []
    tried = list(grasps(instance))
    with ThreadPoolExecutor(2) as pool:
        grades = list(pool.map(lambda g: lift(mesh, g), tried))
    for g, grade in zip(tried, grades):
        c = counts.setdefault(g[0], {'tests': 0, 'success': 0, 'partial': 0})
        c['tests'] += 1
        if grade in ('success', 'partial'):
            c[grade] += 1
        if grade == 'success':
            best.append([g[0]] + [round(v, 4) for v in g[1:]])
    lifted = sum(c['success'] for c in counts.values())
    return {'hammer': os.path.basename(mesh), 'origin': origin,
            'head_section_mm': round(1000 * instance['params']['head_section_m'], 1),
            'tests': len(tried), 'success': lifted, 'families': counts,
            'some successes (family, x, y, roll, pitch, yaw, preshape, spread)': best[:4]}


with tempfile.TemporaryDirectory() as tmp:
    sets = [('held-apart', 1, 10, 'eval novel'), ('training', 1, 4, 'database')]
    for family, seed, count, origin in sets:
        out = os.path.join(tmp, family)
        for instance in generate(out, family, seed, count):
            if ARGS and instance['file'] not in ARGS:
                continue
            print(json.dumps(survey(os.path.join(out, instance['file']), instance, origin)), flush=True)
