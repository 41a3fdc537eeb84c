"""Several training configs side by side on one lent GPU, inside one call's wall-clock budget.

A GPU comes to this project by chance, for about 15 minutes of one session, in calls of at most 10 minutes.
This driver is what ran in such a call (2026-11-26, an H200; MODEL_CARD.md): nothing else in the project
needs a GPU, and ``python -m training.train --device cuda`` trains any config on one without it.

1. Calibration: every config trains concurrently for ``--calibrate`` minutes with a schedule that never
   decays (throwaway run directories); its step rate is read off its log.
2. The real runs: each config's ``steps_per_epoch`` is set so that its ``epochs`` (lr x0.1 at the
   milestones) end inside the budget at that rate (times ``--safety``); all train concurrently again with
   ``--stop-at`` as a backstop. The configs as run (what to commit) go to ``OUT/configs.json``, each run's
   checkpoints and log to ``OUT/<name>.tgz`` (``last.pt``, and ``best.pt`` where both fit in 15.5 MB: a
   file back from the device is at most 16 MiB).

    python3 -m training.gpu_burst --budget 555 --out $OUT --data-h36m DIR/h36m_model_cache.npz \\
        --data-humaneva DIR/humaneva_i_15j_60hz.npz training/configs/A.json training/configs/B.json

The data travel with the call in a folder the repository ignores (``python -m training.train
--write-cache`` makes the Human3.6M cache, 20 MB). What was measured with it: the step on the GPU is bound by
the device, not by the host, so runs side by side share it (MODEL_CARD.md, "Trained on a lent GPU").
"""
from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tarfile
import threading
import time
from pathlib import Path

T0 = time.time()


def say(*a):
    print(f"[{time.time() - T0:6.1f}s]", *a, flush=True)


def step_rate(log: str, steps_per_epoch: int) -> float | None:
    """Steps per second from a ``training.train`` log: between the second and the last of its periodic
    ``epoch E batch B/... Ns`` lines (the first steps' warm-up left out) where there are three or more, else
    over the whole run from its ``stopped after M min ... epoch E batch B`` line; None without either."""
    pts = [(int(e) * steps_per_epoch + int(b), float(s)) for e, b, s in
           re.findall(r"epoch (\d+) batch (\d+)/\d+ loss \S+ lr \S+ (\d+)s", log)]
    if len(pts) >= 3 and pts[-1][1] > pts[1][1]:
        return (pts[-1][0] - pts[1][0]) / (pts[-1][1] - pts[1][1])
    m = re.search(r"stopped after ([\d.]+) min of training at epoch (\d+) batch (\d+)", log)
    if m and float(m.group(1)) > 0:
        return (int(m.group(2)) * steps_per_epoch + int(m.group(3))) / (float(m.group(1)) * 60)
    return None


def sized(cfg: dict, rate: float, seconds: float, safety: float) -> dict:
    """``cfg`` with the ``steps_per_epoch`` that fits its ``epochs`` into ``seconds`` at ``rate`` steps/s."""
    steps = int(rate * seconds * safety)
    return dict(cfg, steps_per_epoch=max(20, steps // cfg["epochs"]))


def monitor(every: float = 45.0) -> None:
    """nvidia-smi's load, memory and power every ``every`` seconds, in the driver's output."""
    def loop():
        while True:
            try:
                q = subprocess.run(["nvidia-smi", "--query-gpu=utilization.gpu,memory.used,power.draw",
                                    "--format=csv,noheader"], capture_output=True, text=True, timeout=10)
                say("gpu:", q.stdout.strip())
            except (OSError, subprocess.SubprocessError) as exc:
                say("nvidia-smi:", exc)
                return
            time.sleep(every)
    threading.Thread(target=loop, daemon=True).start()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m training.gpu_burst", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("configs", nargs="+", help="training configs (JSON), trained side by side")
    ap.add_argument("--budget", type=float, default=555, help="seconds from start the whole driver may take")
    ap.add_argument("--calibrate", type=float, default=0.6, help="minutes of the calibration runs")
    ap.add_argument("--safety", type=float, default=0.95, help="fraction of the measured rate planned on")
    ap.add_argument("--out", default=os.environ.get("OUT", "runs/gpu_burst"), help="where results go")
    ap.add_argument("--work", default="runs/gpu_burst_work", help="run directories and logs")
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--workers", type=int, default=2, help="batch-drawing processes per run")
    ap.add_argument("--data-h36m", default=None, help="the Human3.6M data or cache for h36m configs")
    ap.add_argument("--data-humaneva", default=None, help="the HumanEva-I data for humaneva configs")
    args = ap.parse_args(argv)
    out, work = Path(args.out), Path(args.work)
    out.mkdir(parents=True, exist_ok=True)
    work.mkdir(parents=True, exist_ok=True)
    data = {"h36m": args.data_h36m, "humaneva": args.data_humaneva}
    env = dict(os.environ, PYTHONUNBUFFERED="1", OMP_NUM_THREADS="2")

    def launch(cfg_path: Path, run: Path, extra: list):
        d = json.loads(cfg_path.read_text())
        cmd = [sys.executable, "-m", "training.train", "--config", str(cfg_path), "--out", str(run),
               "--device", args.device, "--workers", str(args.workers), *extra]
        if data[d.get("dataset", "h36m")]:
            cmd += ["--data", data[d.get("dataset", "h36m")]]
        log = open(run.with_suffix(".log"), "w")
        return subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=env), log

    def wait_all(procs: dict, until: float) -> None:
        for name, (p, log) in procs.items():
            try:
                p.wait(timeout=max(1.0, until - time.time()))
            except subprocess.TimeoutExpired:
                say(f"{name}: past its time, killed")
                p.kill()
                p.wait()
            log.close()

    if args.device == "cuda":
        monitor()
    configs = {Path(c).stem: Path(c) for c in args.configs}
    # 1. calibration: a schedule that never decays, no validation
    procs, starts = {}, {}
    for name, path in configs.items():
        cal = work / f"cal_{name}.json"
        cal.write_text(json.dumps(dict(json.loads(path.read_text()), epochs=1000, steps_per_epoch=100,
                                       val_every=1000), indent=1))
        starts[name] = time.time()
        procs[name] = launch(cal, work / f"cal_{name}", ["--max-minutes", str(args.calibrate)])
    wait_all(procs, time.time() + args.calibrate * 60 + 120)
    rates, overhead = {}, {}
    for name in configs:
        text = (work / f"cal_{name}.log").read_text()
        rate = step_rate(text, 100)
        trained = re.search(r"stopped after ([\d.]+) min", text)
        if rate is None or procs[name][0].returncode != 0 or not trained:
            say(f"{name}: calibration failed (exit {procs[name][0].returncode}); its log's end:\n" + text[-3000:])
            continue
        rates[name] = rate
        overhead[name] = max(10.0, time.time() - starts[name] - float(trained.group(1)) * 60)
        say(f"{name}: {rate:.2f} steps/s, set-up and close {overhead[name]:.0f} s; log head:\n" + text[:600])
    # 2. the real runs
    deadline = T0 + args.budget - 30
    final, procs = {}, {}
    for name, rate in rates.items():
        seconds = deadline - time.time() - overhead[name]
        d = sized(json.loads(configs[name].read_text()), rate, seconds, args.safety)
        final[name] = d
        path = work / f"{name}.json"
        path.write_text(json.dumps(d, indent=1) + "\n")
        say(f"{name}: {d['epochs']} x {d['steps_per_epoch']} steps of batch {d['batch_size']} "
            f"({d['epochs'] * d['steps_per_epoch'] * d['batch_size']:,} windows) in {seconds:.0f} s")
        procs[name] = launch(path, work / name, ["--stop-at", str(deadline)])
    (out / "configs.json").write_text(json.dumps({"rates_steps_per_s": rates, "configs": final}, indent=1))
    wait_all(procs, deadline + 25)
    for name in procs:
        text = (work / f"{name}.log").read_text()
        say(f"{name}: exit {procs[name][0].returncode}; log tail:\n" + text[-700:])
        files = [work / name / f for f in ("last.pt", "best.pt") if (work / name / f).is_file()]
        if sum(f.stat().st_size for f in files) > 15.5e6:
            files = files[:1]
        with tarfile.open(out / f"{name}.tgz", "w:gz") as tf:
            for f in files:
                tf.add(f, arcname=f"{name}/{f.name}")
            tf.add(work / f"{name}.log", arcname=f"{name}/train.log")
    say("done")
    return 0 if len(rates) == len(configs) else 1


if __name__ == "__main__":
    sys.exit(main())
