"""`ssf odom run`, `ssf eval odom` and `ssf bench odom`."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ssf_common.command_groups import CommandGroups

ALL_METHODS = ("points", "flow", "ssf", "kiss-icp")  # the default rows
KNOWN_METHODS = (*ALL_METHODS, "ssf+twist")  # and ssf with the vehicle's measured motion (wheel speed, gyro)
DENSITIES = ("sparse_50", "urban_200", "dense_500", "crowd_1000")


def register(groups: CommandGroups) -> None:
    """Add `ssf odom run`, `ssf eval odom` and `ssf bench odom`."""
    odom = groups.top.add_parser("odom", help="odometry from semantic scene flow over a folder of scans or a bag")
    odom_commands = odom.add_subparsers(dest="odom_command", metavar="WHAT", required=True)
    run = odom_commands.add_parser(
        "run", help="odometry over a folder of scans (.bin, .pcd, .ply, .npy) or a rosbag with a PointCloud2 topic",
        description="Poses of every scan in the first scan's frame: DIR/poses_kitti.txt (KITTI odometry rows), "
        "DIR/poses_tum.txt (timestamp tx ty tz qx qy qz qw), DIR/config.yaml (the effective config) and "
        "DIR/trajectory.png. Folder scans are taken in name order, --period apart; bag scans carry their stamps. "
        "Method ssf (default) runs the flow <-> segmentation loop on each pair of whole scans; flow uses the flow "
        "alone; points registers whole scans only. -p names: odom.* (odometry) and perception.* (flow.*, seg.*, "
        "fusion.*).")
    run.add_argument("source", type=Path, metavar="SOURCE", help="folder of scans or a rosbag (folder or .mcap/.db3)")
    run.add_argument("--out", type=Path, required=True, metavar="DIR", help="output folder")
    run.add_argument("--method", choices=("points", "flow", "ssf"), default=None, help="default: ssf (or the config's)")
    run.add_argument("--topic", help="PointCloud2 topic of the bag (default: its only one)")
    run.add_argument("--period", type=float, default=0.1, metavar="S", help="time between folder scans (default 0.1 s)")
    run.add_argument("--config", type=Path, help="YAML with odom.* and perception.* sections")
    run.add_argument("-p", "--param", action="append", default=[], metavar="NAME:=VALUE",
                     help="override one config value, e.g. -p odom.map.voxel:=0.5")
    run.add_argument("--device", default="cpu", help="torch device for network flow estimators")
    run.set_defaults(func=run_odom)

    evaluate = groups.eval.add_parser(
        "odom", help="RPE (RMSE/SSE/STD), ATE, drift and map trails per method and KISS-ICP, per traffic density",
        description="Every odometry method and KISS-ICP on the very same simulated whole scans. Flow comes from the "
        "project's `rigid` estimator on whole scans; the static mask from the segmentation's fusion loop (--masks "
        "seg), or ground-truth stand-ins (gt, noisy) for ablations. RPE/ATE computed with evo; drift over the route "
        "segments of the KITTI protocol the drive is long enough for, and end-point error in %% of the distance.")
    evaluate.add_argument("--scenario", "--scenarios", dest="scenarios", nargs="+", default=list(DENSITIES), metavar="NAME",
                          help=f"scenarios (default: {' '.join(DENSITIES)})")
    evaluate.add_argument("--agents", type=int, help="override every scenario's agent count")
    evaluate.add_argument("--sim-param", action="append", default=[], metavar="NAME:=VALUE",
                          help="scenario setting of every simulated drive, e.g. --sim-param lidar.rolling_shutter:=true "
                          "(repeatable)")
    evaluate.add_argument("--seed", type=int, default=0, help="simulator seed (default 0; tuning used 10-19)")
    evaluate.add_argument("--frames", type=int, default=300, help="scans per scenario (default 300: 30 s of driving)")
    evaluate.add_argument("--warmup", type=float, default=2.0, metavar="S", help="simulated seconds before the first scan")
    evaluate.add_argument("--methods", "--method", nargs="+", default=list(ALL_METHODS), metavar="M",
                          help=f"default: {' '.join(ALL_METHODS)}; also ssf+twist: ssf with the simulated vehicle's "
                          "measured motion (wheel speed, yaw-rate gyro; the paper's '+ IMU' row)")
    evaluate.add_argument("--masks", choices=("seg", "gt", "noisy", "agents"), default="seg",
                          help="static mask: the segmentation (fusion loop), or ground truth (gt, noisy) stand-ins; "
                          "agents: every point on an agent, standing or moving (a world without traffic in the map)")
    evaluate.add_argument("--trail-every", type=int, default=10, help="sample the maps' trails every N scans")
    evaluate.add_argument("--json", type=Path, help="write the results here (and the effective config beside them)")
    evaluate.add_argument("--plot", type=Path, help="PNG: every method's trajectory against the truth")
    evaluate.add_argument("--map-plot", type=Path, help="PNG: the local maps of the last scenario, trails in red")
    evaluate.add_argument("--poses", type=Path, metavar="DIR",
                          help="write every trajectory in the TUM format: DIR/SCENARIO_METHOD_tum.txt and "
                          "DIR/SCENARIO_truth_tum.txt (poses in the first scan's frame), for evo or a closer look")
    evaluate.add_argument("--perception-cache", type=Path, metavar="DIR",
                          help="store each scan's flow and mask under DIR/SCENARIO/ and read them back on a later run "
                          "of the same drive (scenario, seed, warm-up, masks, perception.* settings): an odometry "
                          "change then reruns a whole route in minutes; start a new DIR after changing perception code")
    add_odom_options(evaluate)
    evaluate.set_defaults(func=run_eval_odom)

    bench = groups.bench.add_parser(
        "odom", help="ms per scan (median, p95) of each odometry method on top of flow and segmentation, peak RSS",
        description="Flow and masks are computed first (rigid flow, noisy ground-truth masks as the fusion loop hands "
        "them); then each method and KISS-ICP (the baseline measured in the same run) are timed on the same scans.")
    bench.add_argument("--scenario", default="urban_200")
    bench.add_argument("--seed", type=int, default=0)
    bench.add_argument("--frames", type=int, default=40, help="timed scans per method (default 40)")
    bench.add_argument("--methods", "--method", nargs="+", default=list(ALL_METHODS), metavar="M")
    bench.add_argument("--backends", action="store_true",
                       help="also time the refinement with numpy (ours), Open3D and small_gicp on the same scans and maps")
    bench.add_argument("--json", type=Path)
    add_odom_options(bench)
    bench.set_defaults(func=run_bench_odom)


def add_odom_options(parser: argparse.ArgumentParser) -> None:
    """--odom-config and -p overrides of the odometry and perception configs."""
    parser.add_argument("--odom-config", type=Path, help="odometry config YAML (method, map.*, refine_gates, ...)")
    parser.add_argument("-p", "--param", action="append", default=[], metavar="NAME:=VALUE",
                        help="override one config value: odometry names as they are (-p map.voxel:=0.5), perception "
                        "names under perception. (-p perception.flow.rigid.end_whole:=false)")


PERCEPTION_PREFIX = "perception."


def split_overrides(args: argparse.Namespace) -> tuple[dict, dict]:
    """The -p overrides as (odometry names, perception names without their `perception.` prefix)."""
    from ssf_common.config import parse_overrides

    odometry, perception = {}, {}
    for name, value in parse_overrides(args.param, "-p").items():
        if name.startswith(PERCEPTION_PREFIX):
            perception[name[len(PERCEPTION_PREFIX):]] = value
        else:
            odometry[name] = value
    return odometry, perception


def perception_overrides(args: argparse.Namespace) -> dict:
    """The -p overrides under perception., without the prefix."""
    return split_overrides(args)[1]


def odom_config(args: argparse.Namespace):
    """The odometry config from --odom-config and -p overrides."""
    from ssf_common.config import build, read_yaml
    from ssf_odom_node.core.odometry import OdomConfig

    file = read_yaml(args.odom_config) if args.odom_config else {}
    return build(OdomConfig, file, split_overrides(args)[0], source=str(args.odom_config or "-p"))


def check_methods(methods: list[str]) -> None:
    """Every name must be a method or kiss-icp."""
    from ssf_common.errors import ConfigError

    unknown = [name for name in methods if name not in KNOWN_METHODS]
    if unknown:
        raise ConfigError(f"unknown odometry method {unknown[0]!r}; choose from {', '.join(KNOWN_METHODS)}")


def perception_for(masks: str, seed: int, overrides: dict | None = None, plain: bool = True):
    """The project's perception on whole scans (ssf_eval.pipeline: flow estimator, segmenter, fusion loop, at their
    whole-scan defaults and `overrides`); the loop runs only when the masks come from the segmentation. `plain`: the
    flow without a mask is wanted too (the 'flow' method)."""
    from ssf_common.config import build
    from ssf_eval.odom.evaluate import OdomMaskSource, OdomPerception
    from ssf_eval.pipeline import PerceptionConfig, PerceptionChain
    from ssf_flow_node.core.estimator import WHOLE_SCAN, make_estimator

    config = build(PerceptionConfig, {"flow": WHOLE_SCAN}, overrides or {}, source="-p perception.*")
    pipeline = PerceptionChain(config)
    segmented = masks == "seg"
    estimator = pipeline.loop.estimator
    maskless = None
    if plain:  # the loop's estimator answers the graph's questions only; the stand-in masks' one asks both
        maskless = make_estimator(config.flow.estimator, config.flow) if segmented else estimator
    return OdomPerception(OdomMaskSource(masks), estimator, pipeline if segmented else None, seed, maskless, config.scan_period)


def format_odom_table(results: dict) -> str:
    """The paper's layout: RPE translation and rotation (RMSE / SSE / STD), then ATE, drift, trails and time."""
    header = (f"{'scenario':<12} {'method':<9} {'RPE t RMSE':>10} {'SSE':>8} {'STD':>7} {'RPE r RMSE':>10} {'SSE':>8} "
              f"{'STD':>7} {'ATE':>7} {'drift %':>7} {'deg/100m':>8} {'end %':>6} {'trails %':>8} {'left %':>6} "
              f"{'ms':>6}")
    lines = [header, "-" * len(header)]
    import numpy as np

    for title, result in results.items():
        for name, s in result.scores.items():
            run = result.runs[name]
            lines.append(
                f"{title:<12} {name:<9} {s.rpe_translation.rmse:10.4f} {s.rpe_translation.sse:8.4f} "
                f"{s.rpe_translation.std:7.4f} {s.rpe_rotation.rmse:10.4f} {s.rpe_rotation.sse:8.4f} "
                f"{s.rpe_rotation.std:7.4f} {s.ate.rmse:7.3f} {s.drift.translation_pct:7.2f} "
                f"{s.drift.rotation_deg_per_100m:8.3f} {s.endpoint_pct:6.2f} {100 * run.trail_share:8.2f} "
                f"{100 * run.left_share:6.2f} {float(np.median(run.ms)):6.1f}")
    return "\n".join(lines)


def format_end_errors(results: dict) -> str:
    """Where each last pose is off: along the ground and in height (m), and roll / pitch / yaw (deg)."""
    lines = ["where the last pose is off (m along the ground, m in height; deg roll, pitch, yaw in the vehicle frame):"]
    for title, result in results.items():
        for name, s in result.scores.items():
            end = s.end
            lines.append(f"  {title:<12} {name:<9} {end.horizontal_m:8.3f} {end.height_m:8.3f} {end.roll_deg:8.3f} "
                         f"{end.pitch_deg:8.3f} {end.yaw_deg:8.3f}")
    return "\n".join(lines)


def run_odom(args: argparse.Namespace) -> int:
    """ssf odom run."""
    from ssf_common.checks import require_finite
    from ssf_common.config import build, parse_overrides, read_yaml
    from ssf_common.paths import check_writable_dir
    from ssf_common.progress import progress_bar
    from ssf_eval.odom.run import OdomRunConfig, Perceiver, open_source, run_odometry, write_outputs
    from ssf_flow_node.core.estimator import WHOLE_SCAN
    from ssf_odom_node.core.odometry import make_odometry

    require_finite(args.period, "--period", above=0.0)
    check_writable_dir(args.out, "output folder")
    layers = [{"perception": {"flow": WHOLE_SCAN, "scan_period": args.period}, "odom": {"scan_period": args.period}}]
    layers += [read_yaml(args.config)] if args.config else []
    layers += [parse_overrides(args.param, "-p")]
    layers += [{"odom": {"method": args.method}}] if args.method else []
    config = build(OdomRunConfig, *layers, source=str(args.config or "-p"))
    source = open_source(args.source, args.topic, args.period)
    odometry = make_odometry(config=config.odom)
    perceive = Perceiver(config.odom.method, config.perception, args.device)
    steps = run_odometry(source, odometry, perceive, progress_bar(max(source.count - 1, 1)))
    written = write_outputs(args.out, steps, config, source)
    last = steps[-1].pose[:3, 3]
    truth = "" if written.end_error_m is None else f" ({written.end_error_m:.2f} m from the true end)"
    print(f"{config.odom.method.value} odometry over {source.description}: {len(steps)} poses, last at ({last[0]:.2f}, {last[1]:.2f}, {last[2]:.2f}) m{truth} -> "
          + ", ".join(str(path) for path in written.paths), file=sys.stderr)
    return 0


def run_eval_odom(args: argparse.Namespace) -> int:
    """ssf eval odom."""
    import numpy as np

    from ssf_common.errors import ConfigError
    from ssf_common.paths import check_writable, check_writable_dir
    from ssf_eval.odom.evaluate import run_sequence
    from sim_bridge.scenario import overrides_from_pairs
    from ssf_eval.odom.sequence import scenario_of, sim_scans
    from ssf_eval.results import write_result

    from ssf_common.checks import require_finite, require_seed

    check_methods(args.methods)
    if args.frames < 2:
        raise ConfigError(f"--frames must be at least 2, got {args.frames}")
    require_seed(args.seed)
    require_finite(args.warmup, "--warmup", at_least=0.0)
    if args.trail_every < 1:
        raise ConfigError(f"--trail-every must be at least 1, got {args.trail_every}")
    for path, what in ((args.json, "result file"), (args.plot, "picture"), (args.map_plot, "picture")):
        if path is not None:
            check_writable(path, what)
    for folder, what in ((args.poses, "poses folder"), (args.perception_cache, "perception cache")):
        if folder is not None:
            check_writable_dir(folder, what)
    config = odom_config(args)
    sim = overrides_from_pairs(args.sim_param, "--sim-param")
    scenarios = [scenario_of(name, args.agents, sim) for name in args.scenarios]
    perception = (perception_for(args.masks, args.seed, perception_overrides(args), plain="flow" in args.methods)
                  if {"flow", "ssf", "ssf+twist"} & set(args.methods) else None)
    results = {}
    for scenario in scenarios:
        title = f"{scenario.name}" if args.agents is None else f"{scenario.name}@{args.agents}"
        print(f"{title}: {args.frames} scans, seed {args.seed}, methods {' '.join(args.methods)}, masks {args.masks}",
              file=sys.stderr, flush=True)
        progress = lambda done: done % 25 == 0 and print(f"  {title}: scan {done}/{args.frames}", file=sys.stderr, flush=True)
        scans = sim_scans(scenario, args.seed, args.frames, args.warmup)
        perceive = perception
        if perception is not None and args.perception_cache is not None:
            from ssf_eval.odom.cache import CachedPerception

            drive = {"scenario": scenario.model_dump(mode="json"), "seed": args.seed, "warmup_s": args.warmup,
                     "perception": perception_overrides(args)}
            perceive = CachedPerception(perception, args.perception_cache / title, drive)
        results[title] = run_sequence(scans, args.methods, perceive, config, config.map.voxel, args.trail_every,
                                      progress)
        if perceive is not perception:
            print(f"  {title}: perception of {perceive.read} scans read from {perceive.folder}, {perceive.computed} "
                  "computed and stored", file=sys.stderr)
    print(f"odometry over {args.frames} scans after {args.warmup:g} s, seed {args.seed}, masks {args.masks} "
          "(RPE between consecutive scans: translation m, rotation deg; ATE m; trails: share of map voxels on agents' "
          "paths; left: of those, where no agent stands at that moment)")
    print(format_odom_table(results))
    print(format_end_errors(results))
    for title, result in results.items():
        floor = result.static_world
        print(f"{title}: the static world itself (the simulator's static points within ssf_range, same voxels) has "
              f"{100 * floor.trail_share:.2f} % on agents' paths, {100 * floor.left_share:.2f} % left behind: the "
              "floor a perfect static map scores (agents standing still are static)")
    if args.json:
        payload = {"seed": args.seed, "frames": args.frames, "warmup_s": args.warmup, "masks": args.masks,
                   "scenarios": {title: {
                       "distance_m": next(iter(result.scores.values())).distance,
                       "perception_ms_median": float(np.median(result.perception_ms)) if result.perception_ms else None,
                       "static_world_trail_share": result.static_world.trail_share,
                       "static_world_left_behind_share": result.static_world.left_share,
                       "methods": {name: {"rpe_translation": s.rpe_translation._asdict(),
                                          "rpe_rotation_deg": s.rpe_rotation._asdict(), "ate": s.ate._asdict(),
                                          "drift": s.drift._asdict(), "endpoint_pct": s.endpoint_pct,
                                          "end_error": s.end._asdict(),
                                          "trail_share": result.runs[name].trail_share,
                                          "left_behind_share": result.runs[name].left_share,
                                          "map_voxels_sampled": result.runs[name].map_voxels,
                                          "ms_median": float(np.median(result.runs[name].ms)),
                                          "ms_p95": float(np.percentile(result.runs[name].ms, 95))}
                                   for name, s in result.scores.items()}}
                       for title, result in results.items()}}
        write_result(args.json, payload, {"odom": config, "perception": perception_overrides(args),
                                          "methods": args.methods, "masks": args.masks,
                                          "scenarios": [s.model_dump(mode="json") for s in scenarios]})
    if args.poses:
        from ssf_eval.odom.evaluate import write_trajectories

        for title, result in results.items():
            written = write_trajectories(result, args.poses, title)
        print(f"trajectories -> {args.poses}/ ({len(written)} files a scenario)", file=sys.stderr)
    if args.plot:
        from ssf_eval.odom.plot import plot_trajectories

        print(plot_trajectories(results, args.plot), file=sys.stderr)
    if args.map_plot:
        from ssf_eval.odom.plot import plot_maps

        title, result = list(results.items())[-1]
        print(plot_maps(result, title, args.map_plot), file=sys.stderr)
    return 0


def run_bench_odom(args: argparse.Namespace) -> int:
    """ssf bench odom: ms per scan of the odometry alone (flow and masks computed beforehand), KISS-ICP beside."""
    import resource
    import time

    import numpy as np

    from ssf_eval.odom.evaluate import KISS_ICP, KissIcpBaseline
    from ssf_eval.odom.sequence import scenario_of, sim_scans
    from ssf_eval.results import check_bench_args, write_result
    from ssf_odom_node.core.odometry import OdomInput, make_odometry

    check_methods(args.methods)
    check_bench_args(args, 2)
    config = odom_config(args)
    scenario = scenario_of(args.scenario)
    perception = perception_for("noisy", args.seed, perception_overrides(args))
    scans, inputs, truths = [], [], []
    print(f"computing flow and masks for {args.frames} scans of {args.scenario} ...", file=sys.stderr, flush=True)
    for scan in sim_scans(scenario, args.seed, args.frames, 2.0):
        perceived = perception(scan)
        scans.append(scan.points)
        truths.append(scan.pose)
        inputs.append({"points": OdomInput(scan.stamp_ns, scan.points),
                       "flow": OdomInput(scan.stamp_ns, scan.points, perceived.flow_plain),
                       "ssf": OdomInput(scan.stamp_ns, scan.points, perceived.flow, perceived.dynamic_prob,
                                        ego=perceived.ego),
                       "ssf+twist": OdomInput(scan.stamp_ns, scan.points, perceived.flow, perceived.dynamic_prob,
                                              measured_motion=scan.measured_motion, ego=perceived.ego)})
    figures = {}
    for name in args.methods:
        spent, cpu = [], []
        steps = (lambda points: kiss.step(points), scans) if name == KISS_ICP else (
            lambda frame: odometry.step(frame[name]), inputs)
        if name == KISS_ICP:
            kiss = KissIcpBaseline()
        else:
            odometry = make_odometry("ssf" if name == "ssf+twist" else name, config)
        run, items = steps
        for item in items:
            started, started_cpu = time.perf_counter(), time.process_time()
            run(item)
            spent.append((time.perf_counter() - started) * 1e3)
            cpu.append((time.process_time() - started_cpu) * 1e3)
        spent, cpu = spent[1:], cpu[1:]  # the first scan only starts the map
        figures[name] = {"ms_median": float(np.median(spent)), "ms_p95": float(np.percentile(spent, 95)),
                         "cpu_ms_median": float(np.median(cpu)), "frames": len(spent),
                         "points": int(np.median([len(points) for points in scans]))}
        print(f"{name:<9} median {figures[name]['ms_median']:6.1f} ms  p95 {figures[name]['ms_p95']:6.1f} ms  "
              f"CPU median {figures[name]['cpu_ms_median']:6.1f} ms", flush=True)
    backends = {}
    if args.backends:
        from ssf_eval.odom.backends import compare_backends

        log = lambda line: print(line, file=sys.stderr, flush=True)
        backends = compare_backends(make_odometry("ssf", config), [frame["ssf"] for frame in inputs], truths, log)
        for name, figure in backends.items():
            print(f"refine {name:<10} median {figure['ms_median']:6.1f} ms  p95 {figure['ms_p95']:6.1f} ms  "
                  f"pose error median {figure['pose_error_median_m']:.4f} m", flush=True)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print(f"peak_rss_mb {peak:.0f}")
    if args.json:
        write_result(args.json, {"methods": figures, "backends": backends, "peak_rss_mb": peak, "scenario": args.scenario},
                     {"odom": config, "methods": args.methods, "scenario": args.scenario, "seed": args.seed})
    return 0
