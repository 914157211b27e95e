"""``python -m disent``: train and evaluate one model (Hydra; see conf/config.yaml).

python -m disent                                      # explicit model, all losses, SynthFaces 64x64
python -m disent model=implicit +ablation=no_bws      # one loss off
python -m disent -m model=baseline,explicit,implicit  # side by side (multirun)
python -m disent +experiment=smoke                    # a few steps, for checks
"""

from __future__ import annotations

from pathlib import Path

import hydra
from omegaconf import DictConfig

import disent.storage  # noqa: F401  (registers ${pid:}, used by the run folder names in conf/config.yaml)


@hydra.main(config_path="../conf", config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> float:
    from hydra.core.hydra_config import HydraConfig

    from disent.config import ConfigError
    from disent.storage import CheckpointError, RunFolderBusy
    from disent.train import run

    try:
        metrics = run(cfg, Path(HydraConfig.get().runtime.output_dir))
    except (ConfigError, RunFolderBusy, CheckpointError) as e:  # one line, no traceback
        raise SystemExit(f"error: {e}") from None
    return metrics["recon_mse"]


if __name__ == "__main__":
    main()
