"""What a training run fits: the model it starts from (`initial_model`), the parameters the
optimizer moves (`trainable`), the parameters only training uses (`TrainingHeads`: proxies, the
shape-parameter read-out) and the losses on the shape code (`shape_terms`: batch-hard, proxies,
parameters, category)."""

from __future__ import annotations

import numpy as np
import torch

from ndfa.core.errors import ModelError
from ndfa.ndf.checkpoint import load_model
from ndfa.ndf.model import NDFModel
from ndfa.sim.categories import CATEGORIES
from ndfa.training.losses import batch_hard_shape_loss, category_loss, parameter_loss, proxy_identity_loss
from ndfa.training.shape_parameters import shape_parameters
from ndfa.training.train_config import TrainConfig
from ndfa.training.validate import mean_codes

TRAIN_ONLY = ("all", "code_head", "center_head", "center_refit", "decoder")


class TrainingHeads(torch.nn.Module):
    """Parameters that only training uses and the shipped model leaves out: one learned proxy code
    per training object (the proxy loss) and a linear read-out of the mugs' shape parameters from
    the code (the parameter loss), each present only when its loss weight is above 0."""

    def __init__(self, config: TrainConfig, model: NDFModel, train_set: dict[str, np.ndarray] | None = None) -> None:
        super().__init__()
        code_dim = model.config.code_dim_out
        objects = config.train_mugs * len(config.categories)  # `object_ids` of the training views
        self.proxies = None
        if config.proxy_weight > 0:
            # A trained model's proxies start at its mean code per object: random ones would pull
            # every code toward noise until they were learnt (measured: the loss stayed near
            # chance, log(400), for 1,000 steps of fine-tuning at lr 2e-4).
            initial = torch.randn(objects, code_dim) if train_set is None else mean_codes(model, train_set, objects)
            self.proxies = torch.nn.Parameter(initial.clone())
        self.param_readout = None
        if config.param_weight > 0:
            if config.categories != ("mug",):
                raise ModelError("the shape-parameter loss reads mugs' parameters: train on mugs alone or set its weight to 0")
            table = torch.from_numpy(shape_parameters("train", list(range(config.train_mugs))))
            # Standardised over the training mugs, so that centimetres and fractions weigh alike.
            self.register_buffer("param_targets", (table - table.mean(0)) / table.std(0).clamp_min(1e-6))
            self.param_readout = torch.nn.Linear(code_dim, table.shape[1])

    def losses(self, codes: torch.Tensor, object_id: torch.Tensor, config: TrainConfig) -> dict[str, torch.Tensor]:
        terms = {}
        if self.proxies is not None:
            terms["proxy"] = proxy_identity_loss(codes, object_id, self.proxies, config.proxy_scale)
        if self.param_readout is not None:
            terms["param"] = parameter_loss(self.param_readout(codes), self.param_targets[object_id])
        return terms


def shape_terms(model: NDFModel, codes: torch.Tensor, labels: dict[str, torch.Tensor], config: TrainConfig,
                heads: TrainingHeads) -> dict[str, torch.Tensor]:
    """The losses on the codes `[B, D]` of views with `labels` (`batches.batch_labels`): the
    batch-hard shape loss over every object (of every category) in the batch, the training heads'
    losses, and the category head's cross-entropy when the model has one."""
    terms = {"shape": batch_hard_shape_loss(codes, labels["object_id"], config.shape_margin)}
    terms |= heads.losses(codes, labels["object_id"], config)
    if model.category_head is not None:
        terms["category"] = category_loss(model.category_logits(codes), model_categories(model, labels["category"]))
    return terms


def model_categories(model: NDFModel, category: torch.Tensor) -> torch.Tensor:
    """Indices into `CATEGORIES` `[B]` -> indices into the model's `NDFConfig.categories`."""
    lookup = torch.tensor([model.config.categories.index(c) if c in model.config.categories else -1 for c in CATEGORIES])
    return lookup[category]


def trainable(model: NDFModel, heads: TrainingHeads, config: TrainConfig) -> list[torch.nn.Parameter]:
    """What the optimizer moves: the part being fitted (the category head, which reads the code,
    with the code head) and the training heads."""
    parts = {"all": [model], "code_head": [model.gram_code, model.category_head], "center_head": [model.center_head],
             "center_refit": [model.center_refit], "decoder": [model.decoder]}
    return [p for part in parts[config.train_only] if part is not None for p in part.parameters()] + list(heads.parameters())


def initial_model(config: TrainConfig) -> NDFModel:
    """A fresh model, or `init_weights`' weights in this run's model; with `train_only`, the part
    to refit starts fresh (the others must fit). A category head that `init_weights` lacks (NDF v2
    as the start of v3) starts fresh."""
    model = NDFModel(config.model)
    if config.train_only not in TRAIN_ONLY:
        raise ModelError(f"train_only must be all, code_head, center_head, center_refit or decoder, not {config.train_only!r}")
    if config.train_only == "center_refit" and not config.model.center_refits:
        raise ModelError("refitting the center needs center_refits > 0 (how many heads to average)")
    if config.train_only == "all" and config.model.center_refits:
        raise ModelError("refitted center heads are fitted with train_only center_refit, on a trained model")
    if config.model.categories and set(config.model.categories) != set(config.categories):
        raise ModelError(f"the model's categories ({', '.join(config.model.categories)}) are not the views' "
                         f"({', '.join(config.categories)})")
    if config.init_weights is None:
        if config.train_only != "all":
            raise ModelError(f"refitting the {config.train_only} needs --init weights")
        return model
    if config.train_only == "code_head" and config.model.code_head != "gram":
        raise ModelError("refitting the code head needs the gram code head")
    if config.init_fresh not in ("none", "code_head", "decoder"):
        raise ModelError(f"init_fresh must be none, code_head or decoder, not {config.init_fresh!r}")
    part = config.train_only if config.train_only != "all" else config.init_fresh
    fresh = {"all": (), "none": (), "code_head": ("gram_code.", "category_head."), "center_head": ("center_head.",),
             "center_refit": ("center_refit.",), "decoder": ("decoder.",)}[part]
    init_model = load_model(config.init_weights)[0]
    if not init_model.config.categories:
        fresh += ("category_head.",)
    kept = {name: value for name, value in init_model.state_dict().items() if not name.startswith(fresh)}
    try:
        missing, unexpected = model.load_state_dict(kept, strict=False)
    except RuntimeError as exc:
        raise ModelError(f"{config.init_weights}: its weights do not fit this run's model ({exc})") from exc
    if unexpected or any(not name.startswith(fresh) for name in missing):
        raise ModelError(f"{config.init_weights}: its weights do not fit this run's model "
                         f"(missing {missing[:5]}, unexpected {unexpected[:5]})")
    return model
