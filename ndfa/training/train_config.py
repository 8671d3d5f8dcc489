"""What `ndfa train` does, as one frozen dataclass (`TrainConfig`): stored with every checkpoint,
compared when a run is resumed."""

from __future__ import annotations

from dataclasses import dataclass, field

from ndfa.ndf.config import NDFConfig
from ndfa.training.views import ViewConfig


@dataclass(frozen=True)
class TrainConfig:
    """Data, model, losses and schedule of a training run (`ndfa.training.train.train`)."""

    model: NDFConfig = field(default_factory=NDFConfig)
    view: ViewConfig = field(default_factory=ViewConfig)
    categories: tuple[str, ...] = ("mug",)  # the object categories of the views (`ndfa.sim.categories`)
    train_mugs: int = 400            # train-split object indices [0, train_mugs) of each category
    views_per_mug: int = 24
    val_mugs: int = 24               # held-out train-split objects of each category, right after the training ones
    val_views_per_mug: int = 8
    batch_mugs: int = 16             # objects per batch, two views each
    steps: int = 8000
    steps_per_epoch: int = 250       # validation, metrics row and checkpoint every epoch
    lr: float = 6e-4                 # the paper's Adam learning rate
    lr_final_fraction: float = 1.0   # cosine decay of lr to this fraction at the last step (1: constant, the paper's)
    init_weights: str | None = None  # start from this checkpoint's weights (a fresh optimizer), e.g. to continue a shipped model
    train_only: str = "all"          # "all", or refit only a fresh "code_head", "center_head", "center_refit" or "decoder" on init_weights' frozen encoder
    init_fresh: str = "none"         # "none", or "decoder" / "code_head": that part starts fresh (e.g. another size), the rest from init_weights; all of it trains
    alpha: float = 0.01              # the paper's shape-loss weight
    shape_margin: float | None = None  # None: the paper's loss; a number: hinge with this margin
    center_weight: float = 1.0
    frame_weight: float = 1.0        # weight of the frame loss (the "frame" decoder's axis and handle); 0: off
    proxy_weight: float = 0.0        # weight of the proxy (cosine-softmax) identity loss on the codes; 0: off
    proxy_scale: float = 16.0        # its logit scale: cosine similarities are multiplied by this
    param_weight: float = 0.0        # weight of the shape-parameter regression from the code (`shape_parameters`); 0: off
    category_weight: float = 0.1     # weight of the category head's cross-entropy (a model with NDFConfig.categories)
    up_tilt_deg: float = 3.0         # with the model's up cue: std. dev. of the random tilt of the true up per view (pose and table errors)
    shape_threshold: float = 0.9     # delta_s, for the validation figures
    seed: int = 0
    threads: int = 2

    def __post_init__(self) -> None:
        object.__setattr__(self, "categories", tuple(self.categories))
