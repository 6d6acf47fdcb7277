"""The cost of a compiled reward expression per call and of one cart-pole picture.

Run: python benchmarks/bench_expr_render.py [--calls N] [--pictures N]

Both are timed in this thread's CPU time (they run wholly in it), so a busy machine slows neither
figure. A reward expression is evaluated once per env step; ``draw_cartpole`` once per rendered
frame (``render_mode="rgb_array"``, 600x400 RGB).
"""

from __future__ import annotations

import argparse
import time
import timeit
from collections.abc import Callable

import numpy as np
from common import table

from bridge.env.render import draw_cartpole
from bridge.task.expr import compile_expression

NAMES = [f"v{i}" for i in range(8)] + ["x", "theta"]
EXPRESSIONS = [
    "x + 1",
    "-(theta**2) - 0.1 * abs(x)",
    "-(theta**2) - 0.1*abs(x) - 0.01*v0**2 + (1 if abs(x) < 2.4 else -10)",
    "clip(v1 * v2, -1, 1) + max(v3, v4, v5) + exp(-v6**2) * cos(theta)",
]


def per_call_us(fn: Callable[[], object], count: int) -> float:
    timer = timeit.Timer(fn, timer=time.thread_time)
    return min(timer.repeat(repeat=3, number=count)) / count * 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=20_000, help="calls per expression and repeat")
    parser.add_argument("--pictures", type=int, default=500, help="pictures per repeat")
    args = parser.parse_args()
    values = np.linspace(-1.0, 1.0, len(NAMES))
    rows = []
    for text in EXPRESSIONS:
        expression = compile_expression(text, NAMES)
        rows.append(
            (f"reward expression `{text}`", f"{per_call_us(lambda e=expression: e(values), args.calls):.2f}")
        )
    rows.append(
        ("draw_cartpole 600x400", f"{per_call_us(lambda: draw_cartpole(0.5, 0.3), args.pictures):.0f}")
    )
    print(table(rows, ("what", "us per call (CPU time, best of 3)")))


if __name__ == "__main__":
    main()
