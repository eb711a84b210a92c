"""The rate of the MLP's matrix products alone on this machine, at the shapes of a field chunk: the forward
(`[M, 256] @ [256, 256]^T` + bias), the input gradient (`[M, 256] @ [256, 256]`) and the weight gradient
(`[256, M] @ [M, 256]`), each timed in a loop after one untimed call; GFLOP/s per product, one JSON line per
(dtype, M). What `profile_step.py`'s matrix-product rate can be compared with.

    OMP_NUM_THREADS=2 python -m benchmarks.speed.gemm_rate [--rows 16384 65536] [--dtypes float32 bfloat16]
"""

from __future__ import annotations

import argparse
import json
import time

import torch


def rate(product, operands: tuple[torch.Tensor, ...], flop: float, min_flop: float = 2e10) -> float:
    """GFLOP/s of `product(*operands)` (one call = `flop`), timed over enough calls for about `min_flop` in all."""
    product(*operands)
    calls = max(1, int(min_flop // flop))
    start = time.perf_counter()
    for _ in range(calls):
        product(*operands)
    return flop * calls / (time.perf_counter() - start) / 1e9


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rows", type=int, nargs="+", default=[16384, 65536], help="sample points per product (M)")
    parser.add_argument("--dtypes", nargs="+", default=["float32", "bfloat16"])
    parser.add_argument("--width", type=int, default=256)
    args = parser.parse_args()
    torch.manual_seed(0)
    for name in args.dtypes:
        dtype = getattr(torch, name)
        w, bias = torch.randn(args.width, args.width, dtype=dtype), torch.zeros(args.width, dtype=dtype)
        for m in args.rows:
            x, g = torch.randn(m, args.width, dtype=dtype), torch.randn(m, args.width, dtype=dtype)
            flop = 2.0 * m * args.width * args.width
            print(json.dumps({
                "dtype": name, "rows": m, "width": args.width, "threads": torch.get_num_threads(),
                "forward_gflop_per_s": round(rate(torch.addmm, (bias, x, w.t()), flop), 1),
                "input_grad_gflop_per_s": round(rate(torch.mm, (g, w), flop), 1),
                "weight_grad_gflop_per_s": round(rate(torch.mm, (g.t(), x), flop), 1),
            }), flush=True)


if __name__ == "__main__":
    main()
