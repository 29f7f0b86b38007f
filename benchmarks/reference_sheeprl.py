"""Reference for `benchmarks/train.py`: full DreamerV3 updates/s of the public port sheeprl 0.8.4
on the same machine, with the same settings (batch 16 x 64, horizon 15, imagination from all
1,024 replayed states, 2 layers of UNITS units, GRU of UNITS, 32 x 32 latents, float32, CPU,
2 threads), on Pendulum-v1 with vector observations. At 128 and 512 units its world model, actor
and critic have exactly the parameter count of ours with `--obs-dim 3 --action-dim 1`.

sheeprl needs its own environment (it pins other packages than d2a); keep the CPU torch:

    python3 -m venv /tmp/sheepvenv
    /tmp/sheepvenv/bin/pip install torch==2.13.0
    /tmp/sheepvenv/bin/pip install sheeprl==0.8.4 -c <(echo torch==2.13.0)
    /tmp/sheepvenv/bin/python benchmarks/reference_sheeprl.py 128 6

One timed update is one call of sheeprl's `train` (a world-model step and an actor-critic step;
batch sampling is outside it, so the reference is, if anything, flattered). The run stops after
warm-up + N timed updates and prints one JSON line on stdout; sheeprl's own output goes to stderr.
"""
import json
import os
import statistics
import sys
import tempfile
import time

UNITS = int(sys.argv[1])
N_UPDATES = int(sys.argv[2])
WARMUP = 2
THREADS = 2
LEARNING_STARTS = 1024
OUT_DIR = tempfile.mkdtemp(prefix="sheeprl_bench_")
os.environ.setdefault("OMP_NUM_THREADS", str(THREADS))
os.environ.setdefault("MKL_NUM_THREADS", str(THREADS))

import torch  # noqa: E402

torch.set_num_threads(THREADS)

import sheeprl  # noqa: E402,F401  (registers the algorithms)
import sheeprl.algos.dreamer_v3.dreamer_v3 as dv3  # noqa: E402
from sheeprl import cli  # noqa: E402


class _Done(Exception):
    pass


_orig_train = dv3.train
_times = []
_info = {}


def _count(m):
    return sum(p.numel() for p in m.parameters())


def timed_train(fabric, world_model, actor, critic, target_critic, world_optimizer, actor_optimizer,
                critic_optimizer, data, aggregator, cfg, *args, **kwargs):
    if not _info:
        torch.set_num_threads(THREADS)
        a = cfg.algo
        wm = a.world_model
        seq_len, batch = data["actions"].shape[:2]
        _info.update(
            params_world_model=_count(world_model),
            params_actor=_count(actor),
            params_critic=_count(critic),
            torch_threads=torch.get_num_threads(),
            torch_version=torch.__version__,
            device=str(fabric.device),
            precision=str(cfg.fabric.precision),
            batch_data_shape=[int(seq_len), int(batch)],
            batch_size=a.per_rank_batch_size,
            seq_len=a.per_rank_sequence_length,
            horizon=a.horizon,
            dense_units=a.dense_units,
            mlp_layers=a.mlp_layers,
            encoder_units_layers=[wm.encoder.dense_units, wm.encoder.mlp_layers],
            decoder_units_layers=[wm.observation_model.dense_units, wm.observation_model.mlp_layers],
            reward_units_layers=[wm.reward_model.dense_units, wm.reward_model.mlp_layers],
            cont_units_layers=[wm.discount_model.dense_units, wm.discount_model.mlp_layers],
            actor_units_layers=[a.actor.dense_units, a.actor.mlp_layers],
            critic_units_layers=[a.critic.dense_units, a.critic.mlp_layers],
            recurrent_state_size=wm.recurrent_model.recurrent_state_size,
            recurrent_dense_units=wm.recurrent_model.dense_units,
            transition_hidden=wm.transition_model.hidden_size,
            representation_hidden=wm.representation_model.hidden_size,
            latent=f"{wm.stochastic_size}x{wm.discrete_size}",
            imagination_starts_per_update=int(seq_len) * int(batch),
            replay_ratio=a.replay_ratio,
            compile=bool(a.compile.enabled),
            cnn_keys=list(a.cnn_keys.encoder),
            mlp_keys=list(a.mlp_keys.encoder),
            env_id=cfg.env.id,
            num_envs=cfg.env.num_envs,
        )
        _info["params_total"] = (
            _info["params_world_model"] + _info["params_actor"] + _info["params_critic"]
        )
        print("BENCH_INFO " + json.dumps(_info), file=sys.stderr, flush=True)
    t0 = time.perf_counter()
    out = _orig_train(fabric, world_model, actor, critic, target_critic, world_optimizer, actor_optimizer,
                      critic_optimizer, data, aggregator, cfg, *args, **kwargs)
    _times.append(time.perf_counter() - t0)
    print(f"BENCH update {len(_times)}: {_times[-1]:.3f}s", file=sys.stderr, flush=True)
    if len(_times) >= WARMUP + N_UPDATES:
        raise _Done()
    return out


dv3.train = timed_train

overrides = [
    "exp=dreamer_v3",
    "env=gym",
    "env.id=Pendulum-v1",
    "env.num_envs=1",
    "env.sync_env=True",
    "env.capture_video=False",
    "algo.cnn_keys.encoder=[]",
    "algo.cnn_keys.decoder=[]",
    "algo.mlp_keys.encoder=[state]",
    "algo.mlp_keys.decoder=[state]",
    "algo.per_rank_batch_size=16",
    "algo.per_rank_sequence_length=64",
    "algo.horizon=15",
    f"algo.dense_units={UNITS}",
    "algo.mlp_layers=2",
    f"algo.world_model.recurrent_model.recurrent_state_size={UNITS}",
    f"algo.world_model.transition_model.hidden_size={UNITS}",
    f"algo.world_model.representation_model.hidden_size={UNITS}",
    "algo.world_model.stochastic_size=32",
    "algo.world_model.discrete_size=32",
    "algo.replay_ratio=1",
    f"algo.learning_starts={LEARNING_STARTS}",
    f"algo.total_steps={LEARNING_STARTS + WARMUP + N_UPDATES + 10}",
    "algo.run_test=False",
    "algo.compile.enabled=False",
    "fabric.accelerator=cpu",
    "fabric.devices=1",
    "fabric.precision=32-true",
    f"num_threads={THREADS}",
    "buffer.size=100000",
    "buffer.memmap=False",
    "buffer.checkpoint=False",
    "checkpoint.every=0",
    "checkpoint.save_last=False",
    "metric.log_level=0",
    "model_manager.disabled=True",
    f"hydra.run.dir={OUT_DIR}/hydra",
    f"log_root={OUT_DIR}/logs",
]
sys.argv = [sys.argv[0]] + overrides
t_start = time.perf_counter()
_stdout = sys.stdout
sys.stdout = sys.stderr  # the config print and the logs of sheeprl go to stderr: stdout has only the JSON line
try:
    cli.run()
except (_Done, SystemExit):
    pass
finally:
    sys.stdout = _stdout
timed = _times[WARMUP:]
if len(timed) < N_UPDATES:
    print(f"only {len(_times)} updates happened", file=sys.stderr)
    sys.exit(1)
med = statistics.median(timed)
print(json.dumps({
    "units": UNITS,
    "updates_per_s": round(1.0 / med, 4),
    "seconds_per_update_median": round(med, 4),
    "seconds_per_update_mean": round(statistics.mean(timed), 4),
    "updates_timed": len(timed),
    "warmup_updates": WARMUP,
    "params_world_model_actor_critic": _info.get("params_total"),
    "torch_threads": _info.get("torch_threads"),
    "wall_s": round(time.perf_counter() - t_start, 1),
}))
