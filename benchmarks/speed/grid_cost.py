"""Per-sample cost of one training step (forward + backward + Adam step) of candidate fields, on random points.

    OMP_NUM_THREADS=1 python -m benchmarks.speed.grid_cost [--points 32768] [--repeats 5]

Rows: the paper's MLP (`RadianceField()`, 8x256, 63 + 27 encoded inputs), the CPU configs' 4x64 MLP, the shipped
K-Planes fields (`simplenerf.model.grid.KPlanesField`) at the sizes of configs/grid/*.yaml, and the other pure-PyTorch
grids considered for the grid backbone, each with the same small decoder (features -> 64 -> 4; K-Planes too, for a
like-for-like row): TensoRF's VM
decomposition, multi-resolution dense 3D grids (`F.grid_sample` on volumes) and a multi-resolution hash grid
(Instant-NGP's encoding, gather based). Printed: parameters, median milliseconds per step, microseconds per sample
point, CPU seconds per step (process time, which a machine shared with other jobs distorts less than wall time).
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Callable

import torch
import torch.nn.functional as F
from torch import nn

from simplenerf.model.fields import RadianceField
from simplenerf.model.grid import PLANE_AXES, KPlanesField, sample_plane
from simplenerf.model.samples import Samples


def decoder(in_dim: int) -> nn.Module:
    return nn.Sequential(nn.Linear(in_dim, 64), nn.ReLU(), nn.Linear(64, 4))


class KPlanesEncoder(nn.Module):
    """The shipped K-Planes planes (`KPlanesField.grid_features`) with the same decoder as the other grids."""

    def __init__(self, resolutions: list[int], features: int) -> None:
        super().__init__()
        self.field = KPlanesField(resolutions=resolutions, features=features)
        self.decoder = decoder(features * len(resolutions))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.decoder(self.field.grid_features(x))


class TensoRFVM(nn.Module):
    """TensoRF's vector-matrix decomposition: sum over the 3 (plane x line) pairs of R components, + decoder."""

    def __init__(self, resolution: int, components: int) -> None:
        super().__init__()
        self.planes = nn.ParameterList(nn.Parameter(0.1 * torch.randn(1, components, resolution, resolution))
                                       for _ in range(3))
        self.lines = nn.ParameterList(nn.Parameter(0.1 * torch.randn(1, components, resolution, 1)) for _ in range(3))
        self.decoder = decoder(3 * components)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        feats = []
        for plane, line, axes, other in zip(self.planes, self.lines, PLANE_AXES, (2, 1, 0), strict=True):
            line_coords = torch.stack([torch.zeros_like(x[:, other]), x[:, other]], dim=-1)
            feats.append(sample_plane(plane, x[:, list(axes)]) * sample_plane(line, line_coords))
        return self.decoder(torch.cat(feats).t())


class DenseGrids(nn.Module):
    """Multi-resolution dense feature volumes (trilinear `grid_sample`), features concatenated, + decoder."""

    def __init__(self, resolutions: list[int], features: int) -> None:
        super().__init__()
        self.grids = nn.ParameterList(nn.Parameter(0.1 * torch.randn(1, features, r, r, r)) for r in resolutions)
        self.decoder = decoder(features * len(resolutions))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        coords = x.view(1, -1, 1, 1, 3)
        feats = [F.grid_sample(g, coords, align_corners=True).view(g.shape[1], -1) for g in self.grids]
        return self.decoder(torch.cat(feats).t())


class HashGrid(nn.Module):
    """Instant-NGP's multi-resolution hash encoding in plain PyTorch (8 corner gathers per level), + decoder."""

    PRIMES = (1, 2654435761, 805459861)

    def __init__(self, levels: int, log2_table: int, features: int, base: int = 16, finest: int = 512) -> None:
        super().__init__()
        growth = math.exp((math.log(finest) - math.log(base)) / (levels - 1))
        self.resolutions = [int(base * growth**level) for level in range(levels)]
        self.table_size = 2**log2_table
        self.tables = nn.Parameter(torch.empty(levels, self.table_size, features).uniform_(-1e-4, 1e-4))
        self.register_buffer("corners", torch.tensor([[i >> 2 & 1, i >> 1 & 1, i & 1] for i in range(8)]))
        self.register_buffer("primes", torch.tensor(self.PRIMES))
        self.decoder = decoder(levels * features)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        feats = []
        for level, res in enumerate(self.resolutions):
            pos = (x + 1) / 2 * (res - 1)
            low = pos.floor().long().clamp(0, res - 2)
            frac = pos - low
            corners = low[:, None, :] + self.corners  # [P, 8, 3]
            if res**3 <= self.table_size:
                index = (corners[..., 0] * res + corners[..., 1]) * res + corners[..., 2]
            else:
                hashed = corners * self.primes
                index = (hashed[..., 0] ^ hashed[..., 1] ^ hashed[..., 2]) % self.table_size
            weights = torch.where(self.corners.bool(), frac[:, None, :], 1 - frac[:, None, :]).prod(-1)  # [P, 8]
            feats.append((self.tables[level][index] * weights[..., None]).sum(1))
        return self.decoder(torch.cat(feats, dim=-1))


def samples(points: int) -> Samples:
    """`points` random samples in the NDC box (64 per ray) with random view directions."""
    rays = points // 64
    zeros = torch.zeros(rays, 64)
    positions = torch.rand(rays, 64, 3) * 2 - 1
    directions = F.normalize(torch.randn(rays, 3), dim=-1)
    return Samples(t=zeros, t_metric=zeros, delta=zeros, positions=positions, directions=directions)


def time_step(module: nn.Module, loss_of: Callable[[Samples], torch.Tensor], points: int, repeats: int):
    """Median (wall seconds, CPU seconds) of forward + backward + Adam step, after one warm-up step."""
    optimizer = torch.optim.Adam(module.parameters(), lr=1e-3)
    walls, cpus = [], []
    for i in range(repeats + 1):
        batch = samples(points)
        wall, cpu = time.perf_counter(), time.process_time()
        loss = loss_of(batch)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        if i:
            walls.append(time.perf_counter() - wall)
            cpus.append(time.process_time() - cpu)
    return sorted(walls)[len(walls) // 2], sorted(cpus)[len(cpus) // 2]


def field_loss(field: nn.Module) -> Callable[[Samples], torch.Tensor]:
    def loss(batch: Samples) -> torch.Tensor:
        out = field(batch)
        return out.raw_density.square().mean() + out.rgb.square().mean()

    return loss


def encoder_loss(model: nn.Module) -> Callable[[Samples], torch.Tensor]:
    return lambda batch: model(batch.positions.reshape(-1, 3)).square().mean()


def candidates() -> list[tuple[str, nn.Module, Callable]]:
    fields = [
        ("paper MLP RadianceField() 8x256", RadianceField()),
        ("CPU-config MLP 4x64", RadianceField(num_layers=4, width=64, skip_layer=2)),
        ("K-Planes demo fine [32,64,128] C16", KPlanesField(resolutions=[32, 64, 128], features=16)),
        ("K-Planes demo coarse [32,64] C8 h32", KPlanesField(resolutions=[32, 64], features=8, hidden=32)),
        ("K-Planes points aug [32] C8 h32", KPlanesField(resolutions=[32], features=8, hidden=32)),
        ("K-Planes LLFF coarse [32,64,128] C8 h32", KPlanesField(resolutions=[32, 64, 128], features=8, hidden=32)),
        ("K-Planes LLFF fine [64,128,256] C16", KPlanesField(resolutions=[64, 128, 256],
                                                             depth_resolutions=[64, 128, 128], features=16)),
        ("K-Planes earlier LLFF fine [64..512] C16", KPlanesField(resolutions=[64, 128, 256, 512],
                                                                  depth_resolutions=[64, 128, 128, 128], features=16)),
    ]
    encoders = [
        ("K-Planes [32,64,128] C16 (same decoder)", KPlanesEncoder([32, 64, 128], 16)),
        ("K-Planes [64,128,256] C16 (same decoder)", KPlanesEncoder([64, 128, 256], 16)),
        ("TensoRF-VM 128 R16", TensoRFVM(128, 16)),
        ("TensoRF-VM 256 R16", TensoRFVM(256, 16)),
        ("dense 3D [32,64,96] C4", DenseGrids([32, 64, 96], 4)),
        ("dense 3D [32,64,128] C8", DenseGrids([32, 64, 128], 8)),
        ("hash L8 T2^16 F2 (16..256)", HashGrid(8, 16, 2, finest=256)),
        ("hash L16 T2^16 F2 (16..512)", HashGrid(16, 16, 2, finest=512)),
    ]
    return [(n, f, field_loss(f)) for n, f in fields] + [(n, m, encoder_loss(m)) for n, m in encoders]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=32768, help="sample points per step")
    parser.add_argument("--repeats", type=int, default=5, help="timed steps per row (median)")
    parser.add_argument("--only", default="", help="rows whose name contains this text")
    args = parser.parse_args()
    torch.manual_seed(0)
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads, {args.points} points per step")
    print("| field | parameters | ms / step | us / sample | CPU s / step |\n|---|---:|---:|---:|---:|")
    for name, module, loss in candidates():
        if args.only not in name:
            continue
        wall, cpu = time_step(module, loss, args.points, args.repeats)
        params = sum(p.numel() for p in module.parameters())
        print(f"| {name} | {params / 1e6:.2f} M | {wall * 1e3:.0f} | {wall / args.points * 1e6:.2f} | {cpu:.3f} |",
              flush=True)


if __name__ == "__main__":
    main()
