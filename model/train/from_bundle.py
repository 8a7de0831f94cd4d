"""Continue training from a packaged bundle: write its weights into a run folder as finished stages.

A bundle holds the phase model, the manifold's decoder and the sampler, which is what the sampler
stage reads from a run folder. Seeding a run folder from one lets a later stage (a preset whose
schedule goes on past ``step``) train on from the shipped model without the run folder that made it.
When the preset's sampler reads the target-velocity flag and the bundle's does not, the flag's
input column starts at zero: the seeded sampler then computes exactly what the bundle did for
targets given with their velocity.
"""

from __future__ import annotations

from pathlib import Path

from model.inference.bundle import Bundle
from model.nets.sampler import TransitionSampler
from model.train.loop import make_optimizer, save_checkpoint
from model.train.pipeline import TrainConfig, fit_to_skeleton, save_stage_weights
from model.train.sampler_stage import trained_parameters
from model.train.velocity_flag import widen_state


def sampler_from_bundle(bundle: Bundle, cfg: TrainConfig) -> TransitionSampler:
    """A sampler of ``cfg.sampler`` holding the bundle's weights (float32), its decoder included."""
    mine, theirs = cfg.sampler.to_dict(), bundle.config.to_dict()
    differ = sorted(k for k in mine if k != "target_velocity_flag" and mine[k] != theirs.get(k))
    if differ:
        raise ValueError(f"the bundle's sampler differs from the preset's in {', '.join(differ)}")
    if cfg.manifold.to_dict() != bundle.manifold_config.to_dict():
        raise ValueError("the bundle's manifold config differs from the preset's")
    if cfg.sampler.target_velocity_flag < bundle.config.target_velocity_flag:
        raise ValueError("the bundle's sampler reads the target-velocity flag and the preset's does not")
    state = {k: v.float() for k, v in bundle.sampler.state_dict().items()}
    sampler = TransitionSampler(cfg.sampler, bundle.sampler.decoder)
    sampler.load_state_dict(widen_state(state, sampler), strict=True)  # the flag's column, zero: as before when it is 1
    return sampler


def seed_run(bundle_dir: Path, cfg: TrainConfig, run_dir: Path, step: int) -> bool:
    """Write the bundle at ``bundle_dir`` into ``run_dir`` as its phase and manifold weights and a sampler
    checkpoint at ``step`` (fresh optimiser moments); False (nothing written) when the run folder has a
    sampler checkpoint already, which the stage then resumes."""
    if (run_dir / "sampler" / "checkpoint.json").is_file():
        return False
    if not 0 < step < cfg.sampler_stage.loop.iterations:
        raise ValueError(f"the step to start from ({step}) must be within the preset's {cfg.sampler_stage.loop.iterations}")
    bundle = Bundle.load(bundle_dir)
    fit_to_skeleton(cfg, bundle.skeleton.num_joints, bundle.skeleton.roles.root)  # as training will, from the data
    if bundle.phase_model is None:
        raise ValueError(f"{bundle_dir} has no phase model, which the sampler stage needs")
    if cfg.phase.to_dict() != bundle.phase_config.to_dict():
        raise ValueError("the bundle's phase config differs from the preset's")
    sampler = sampler_from_bundle(bundle, cfg)
    save_stage_weights(bundle.phase_model.float(), run_dir / "phase", cfg.phase.to_dict())
    save_stage_weights(sampler.decoder, run_dir / "manifold", cfg.manifold.to_dict())
    optimizer = make_optimizer(trained_parameters(sampler, cfg.sampler_stage.train_decoder), cfg.sampler_stage.loop,
                               cfg.sampler_stage.lr_scales)
    save_checkpoint(run_dir / "sampler", sampler, optimizer, step, [],
                    {"seeded_from": str(bundle_dir), "bundle_version": bundle.version})
    return True
