"""The benchmarks' results as short text reports, each ending with what its ratio means."""

from __future__ import annotations


def format_raycast(rows: list[dict]) -> str:
    """A small text table of :func:`~orthomvp.bench.raycast.bench_raycast` results."""
    triangles = next((f"{r['triangles']:,}" for r in rows if "triangles" in r), "?")
    lines = [
        f"ray casting: {rows[0]['rays']:,} rays onto {triangles} triangles",
        f"{'backend':<8} {'build s':>8} {'raw Mray/s':>11} {'wrapper Mray/s':>15} {'ratio':>6}",
    ]
    for r in rows:
        if "unavailable" in r:
            lines.append(f"{r['backend']:<8} not available: {r['unavailable']}")
            continue
        lines.append(
            f"{r['backend']:<8} {r['build_s']:>8.2f} {r['raw_rays_per_s'] / 1e6:>11.3f} "
            f"{r['wrapper_rays_per_s'] / 1e6:>15.3f} {r['ratio']:>6.2f}"
        )
    lines.append("ratio = wrapper throughput / bare backend call on the same rays, same run")
    return "\n".join(lines)


def format_ortho(row: dict) -> str:
    """A text summary of :func:`~orthomvp.bench.ortho.bench_ortho`."""
    return "\n".join(
        [
            f"occlusion-aware orthophoto: {row['posts']:,} posts "
            f"(mesh + BVH build {row['build_s']:.1f} s, not counted)",
            f"  bare Embree cast, one ray per post: {row['raw_cast_s']:.2f} s",
            f"  orthophoto with occlusion:          {row['ortho_s']:.2f} s "
            f"({row['posts_per_s'] / 1e6:.2f} M posts/s), ratio {row['ratio']:.2f}",
            f"  naive orthophoto (--no-occlusion, no rays): {row['naive_ortho_s']:.2f} s",
            "ratio = orthophoto time / bare cast time on the same rays, same run",
        ]
    )


def format_linescan(row: dict) -> str:
    """A text summary of :func:`~orthomvp.bench.linescan.bench_linescan`."""
    return "\n".join(
        [
            f"line scan: ground to image of {row['project_points']:,} points: "
            f"{row['project_points_per_s'] / 1e6:.2f} M points/s ({row['lines']:,} lines, "
            f"sensor-state table within {row['table_error_px']:.1e} px)",
            f"  orthophoto with occlusion, {row['posts']:,} posts: frame camera "
            f"{row['frame_ortho_s']:.2f} s, line scanner {row['linescan_ortho_s']:.2f} s, "
            f"ratio {row['ratio']:.2f}",
            "ratio = line-scan orthophoto time / frame orthophoto time, same grid, same run",
        ]
    )


def format_mvp(row: dict) -> str:
    """A text summary of :func:`~orthomvp.bench.mvp.bench_mvp`."""
    return "\n".join(
        [
            f"MVP fit, {row['size']} x {row['size']} posts, {row['views']} views, "
            f"hwin {row['hwin']}: {row['fitted']:,} posts fitted in {row['fit_s']:.1f} s "
            f"({row['posts_per_s']:,.0f} posts/s); height RMSE {row['rmse_m']:.2f} m "
            f"(initial {row['initial_rmse_m']:.2f} m)",
            f"  bilinear samples taken by the fit: {row['samples'] / 1e6:,.0f} M",
            f"  bare cv2.remap of as many samples (value and gradients, 3 per position): "
            f"{row['remap_s']:.2f} s; ratio {row['ratio']:.1f}x",
            f"  kernel compile (numba, fresh process, empty cache): "
            f"{row['kernel_compile_s']:.1f} s; first call in this run: "
            f"{row['kernel_first_call_s']:.2f} s (not in the fit time)",
            f"ratio = fit time ({row['fit_threads']} worker threads) / bare cv2.remap time "
            f"(one call at a time, {row['cv2_threads']} cv2 threads), same run",
        ]
    )


def format_orthority(row: dict) -> str:
    """A text summary of :func:`~orthomvp.bench.peer.bench_orthority`."""
    rows, cols = row["grid"]
    return "\n".join(
        [
            f"side by side with Orthority {row['orthority_version']}: {row['case']} onto "
            f"{cols} x {rows} posts of {row['res_m']:g} m, best of {row['repeat']}, "
            f"{row['threads']} threads, from files to GeoTIFF with overviews for both",
            "                              in process          whole process (command line)",
            f"  Orthority (no occlusion):   {row['orthority_s']:7.3f} s            "
            f"{row['orthority_cli_s']:7.3f} s",
            f"  orthomvp, occlusion on:     {row['orthomvp_s']:7.3f} s, ratio "
            f"{row['ratio']:5.2f}  {row['orthomvp_cli_s']:7.3f} s, ratio {row['cli_ratio']:5.2f}",
            f"  orthomvp, occlusion off:    {row['orthomvp_naive_s']:7.3f} s, ratio "
            f"{row['naive_ratio']:5.2f}  {row['orthomvp_naive_cli_s']:7.3f} s, ratio "
            f"{row['cli_naive_ratio']:5.2f}",
            "  orthomvp steps with occlusion, in process: "
            + ", ".join(f"{k} {v:.3f} s" for k, v in row["orthomvp_steps_s"].items()),
            f"ratio = orthomvp time / Orthority time, same run; largest difference of the two "
            f"orthophotos where both have data: {row['max_abs_diff']:.3g}",
            *(_mosaic_lines(row) if "mosaic_cli_ratio" in row else []),
        ]
    )


def _mosaic_lines(row: dict) -> list[str]:
    """The mosaic part of :func:`format_orthority`."""
    rows, cols = row["mosaic_grid"]
    n = row["mosaic_frames"]
    return [
        f"all {n} frames, whole processes: orthomvp's mosaic ({cols} x {rows} posts) against "
        f"Orthority's {n} orthophotos (one oty frame process)",
        f"  Orthority:                  {row['orthority_mosaic_cli_s']:7.3f} s",
        f"  orthomvp mosaic:            {row['orthomvp_mosaic_cli_s']:7.3f} s, ratio "
        f"{row['mosaic_cli_ratio']:5.2f}",
    ]
