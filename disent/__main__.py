"""``python -m disent``: train and evaluate one model (Hydra; see conf/config.yaml).

python -m disent                                      # explicit model, all losses, SynthFaces 64x64
python -m disent model=implicit +ablation=no_bws      # one loss off
python -m disent -m model=baseline,explicit,implicit  # side by side (multirun)
python -m disent +experiment=smoke                    # a few steps, for checks
python -m disent -m seed=0,1,2 train.together=true    # the sweep's runs trained side by side in one process
"""

from __future__ import annotations

from pathlib import Path

import hydra
from omegaconf import DictConfig

import disent.storage  # noqa: F401  (registers ${pid:}, used by the run folder names in conf/config.yaml)


@hydra.main(config_path="../conf", config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> float:
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode

    from disent.config import ConfigError
    from disent.storage import CheckpointError, RunFolderBusy
    from disent.together import queue_run
    from disent.train import run

    hydra_cfg = HydraConfig.get()
    run_dir = Path(hydra_cfg.runtime.output_dir)
    try:
        if cfg.train.get("together", False) and hydra_cfg.mode == RunMode.MULTIRUN:  # trained at the sweep's end
            return queue_run(cfg, run_dir, hydra_cfg.launcher._target_)
        metrics = run(cfg, run_dir)
    except (ConfigError, RunFolderBusy, CheckpointError) as e:  # one line, no traceback
        raise SystemExit(f"error: {e}") from None
    return metrics["recon_mse"]


if __name__ == "__main__":
    main()
