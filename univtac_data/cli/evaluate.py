"""``univtac-data evaluate``: run a policy on a task and report its success rate."""

from __future__ import annotations

import argparse
import json
import os
import sys
from typing import Any

from univtac_data.cli.args import camera_size, check_output_dir, check_output_file, positive_int
from univtac_data.schema.sensors import SENSORS
from univtac_data.storage.errors import DatasetError


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "evaluate", help="run a policy on a task: success rate with a 95 %% Wilson interval, safety, steps",
        description="Run --episodes rollouts of a policy on evaluation seeds (1,000,000 + --seed + k; generation "
                    "never uses them) and print the success rate with a 95 %% Wilson interval, the rate of "
                    "tactile-safety violations and the mean number of steps. A rollout whose policy raises or "
                    "returns a bad action counts as a failure and is reported; the evaluation goes on.",
        epilog="examples: univtac-data evaluate lift_can --policy expert --episodes 20; "
               "univtac-data evaluate lift_can --policy replay:out/tasks; "
               "univtac-data evaluate lift_can --policy mypkg.policies:make_policy --json results.json",
    )
    parser.add_argument("name", metavar="NAME", help="task name (univtac-data generate task NAME)")
    parser.add_argument("--policy", required=True,
                        help="expert | zero | random | replay:DATASET | module:factory (factory() returns an object "
                             "with reset() and act(obs) -> (8,) absolute action)")
    parser.add_argument("--episodes", type=positive_int, default=100, help="rollouts (default 100)")
    parser.add_argument("--seed", type=int, default=0, help="evaluation seed offset (default 0)")
    parser.add_argument("--sensor", default="gelsight_mini", choices=list(SENSORS))
    parser.add_argument("--contact", choices=("geometric", "elastic"), default="geometric")
    parser.add_argument("--camera-size", type=camera_size, default=(480, 270), metavar="WxH", help="camera size (default 480x270)")
    parser.add_argument("--no-cameras", action="store_true", help="observe no camera images (faster)")
    parser.add_argument("--tactile-extras", action="store_true",
                        help="also observe each pad's depth (mm), marker positions (px) and force (N) under "
                             "obs['tactile'] (TaskEnv's tactile_extras)")
    parser.add_argument("--rate-hz", type=float, default=50.0, metavar="HZ",
                        help="policy steps a second (default 50, the tasks' rate; a whole number of 2 ms ticks); "
                             "the step limit is kept as a time limit (max_steps x HZ / 50)")
    parser.add_argument("--json", default=None, metavar="FILE", help="write the summary and every rollout to FILE")
    parser.add_argument("--video", default=None, metavar="DIR",
                        help="write MP4s of the first rollouts to DIR (head camera beside both tactile images; "
                             "needs the [video] extra)")
    parser.add_argument("--videos", type=positive_int, default=3, help="how many rollouts --video records (default 3)")
    return parser


def run(args: argparse.Namespace) -> int:
    from univtac_data.envs.evaluate import evaluate
    from univtac_data.generators.tasks.registry import UnknownTaskError, task_class

    try:
        task_class(args.name)
    except UnknownTaskError as error:
        raise DatasetError(str(error)) from None
    if args.seed < 0:
        raise DatasetError(f"--seed must be >= 0 (got {args.seed})")
    from univtac_data.generators.tasks.base import TaskConfig

    try:
        TaskConfig(rate_hz=args.rate_hz).ticks_per_step
    except ValueError as error:
        raise DatasetError(f"--rate-hz: {error}") from None
    if args.json is not None:
        check_output_file(args.json, "--json")  # before the rollouts, not after them
    if args.video is not None:
        check_output_dir(args.video, "--video")
        from univtac_data.export.video import require_av

        require_av()
    env_kwargs = {"sensor": args.sensor, "contact": args.contact, "cameras": not args.no_cameras,
                  "camera_size": args.camera_size, "rate_hz": args.rate_hz,
                  "tactile_extras": args.tactile_extras}
    report = evaluate(args.name, args.policy, episodes=args.episodes, seed=args.seed, env_kwargs=env_kwargs,
                      video_dir=args.video, videos=args.videos, progress=sys.stderr.isatty())
    s = report.summary()
    lo, hi = s["wilson95"]
    print(f"{args.name} with {args.policy}: success {report.successes}/{report.n} = {s['success_rate']:.1%} "
          f"(95 % Wilson {lo:.1%}-{hi:.1%}); unsafe {s['unsafe_rate']:.1%}; errors {s['errors']}; "
          f"mean steps {s['mean_steps']:.1f}; {s['steps_per_s']:.1f} steps/s")
    for r in report.rollouts:
        if r.reason.startswith("error"):
            print(f"rollout seed {r.seed}: {r.reason}", file=sys.stderr)
    if args.json:
        os.makedirs(os.path.dirname(os.path.abspath(args.json)), exist_ok=True)
        tmp = args.json + ".part"
        with open(tmp, "w") as handle:
            json.dump(report.as_json(), handle, indent=1)
        os.replace(tmp, args.json)
    return 0
