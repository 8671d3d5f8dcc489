"""Every detected object carries a category (issue 33 item 5): the NDF's `category_probabilities`
when the model has a category head, "unknown" when it has none (NDF v2, mugs alone); through the
measurements to the objects (a vote of their views), the decisions, the tables and their replay."""

import numpy as np
import pytest
import torch

from ndfa.change.associate import Measurement, SessionMap
from ndfa.core.conventions import UNKNOWN_CATEGORY
from ndfa.core.events import ObservationEvent
from ndfa.log.table_sink import TableSink
from ndfa.ndf.config import NDFConfig
from ndfa.ndf.encoder import EncoderConfig, NDFEncoder
from ndfa.ndf.model import NDFModel
from ndfa.run.replay import observation_of
from ndfa.training.checkpoint import save_checkpoint

CATEGORIES = ("mug", "bowl", "box")


@pytest.fixture(scope="module")
def clouds():
    rng = np.random.default_rng(0)
    return [rng.normal(size=(200, 3)) * [0.03, 0.04, 0.05] + [0.0, 0.0, 0.8] for _ in range(3)]


@pytest.fixture(scope="module")
def weights_with_categories(tmp_path_factory):
    config = NDFConfig(hidden=8, latent=16, knn=8, encoder_blocks=1, decoder_width=16, decoder_blocks=1, code_dim=8,
                       gram_channels=4, up_cue=True, view_cue=True, center_head="gated", decoder="frame", local_points=4,
                       categories=CATEGORIES)
    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("ndf") / "tiny.pt"
    save_checkpoint(path, NDFModel(config).eval(), config, {"n_points": 64})
    return path


@pytest.mark.parametrize("runtime", ["torch", "onnxruntime"])
def test_a_model_with_a_category_head_names_each_views_category(weights_with_categories, clouds, runtime):
    encoder = NDFEncoder(weights_with_categories, EncoderConfig(runtime=runtime))
    assert encoder.categories == CATEGORIES
    codes = encoder.encode_batch(clouds, [np.eye(4)] * len(clouds))
    with torch.no_grad():
        points = np.stack([encoder.resample(c) for c in clouds])
        z, _, _ = encoder.latent(points, [np.eye(4)] * len(clouds))
        expected = torch.softmax(encoder.model.category_logits(encoder.model.shape_code(z)), dim=-1).numpy()
    for code, probabilities in zip(codes, expected):
        assert code.category == CATEGORIES[int(np.argmax(probabilities))]
        assert code.category_probability == pytest.approx(probabilities.max(), abs=1e-4)


def test_the_shipped_mug_model_says_unknown(clouds):
    """NDF v2 has no category head: its objects' category is not made up (not even "mug")."""
    encoder = NDFEncoder(config=EncoderConfig(runtime="torch"))
    assert encoder.categories == ()
    code = encoder.encode(clouds[0], np.eye(4))
    assert code.category == UNKNOWN_CATEGORY and np.isnan(code.category_probability)


def _measurement(frame: int, category: str, probability: float) -> Measurement:
    return Measurement(frame, 1, np.ones(8), np.array([0.0, 0.0, 0.8]), 0.6, category=category,
                       category_probability=probability)


def test_an_object_takes_the_category_most_of_its_views_probability_went_to():
    session = SessionMap()
    for frame, (category, probability) in enumerate([("bowl", 0.5), ("cup", 0.9), ("bowl", 0.6), ("cup", 0.1)]):
        session.update(_measurement(frame, category, probability))
    (obj,) = session.objects.values()
    assert obj.category == "bowl" and obj.category_share == pytest.approx(1.1 / 2.1)
    unknown = SessionMap()
    unknown.update(_measurement(0, UNKNOWN_CATEGORY, float("nan")))
    assert unknown.objects[0].category == UNKNOWN_CATEGORY and np.isnan(unknown.objects[0].category_share)


def test_the_observations_table_keeps_the_category_for_a_replay(tmp_path):
    sink = TableSink(tmp_path)
    sink.log(ObservationEvent(session="source", frame_index=3, instance_id=2, n_pixels=900, skipped=None, n_points=400,
                              shape_code=np.ones(8), center_world=np.array([1.0, 2.0, 0.8]), mean_occupancy=0.6,
                              category="box", category_probability=0.75))
    (row,) = sink.tables()["observations"].iter_rows(named=True)
    assert (row["category"], row["category_probability"]) == ("box", 0.75)
    measurement = Measurement.of(observation_of(row))
    assert (measurement.category, measurement.category_probability) == ("box", 0.75)
    del row["category"], row["category_probability"]  # a table written before the categories
    assert Measurement.of(observation_of(row)).category == UNKNOWN_CATEGORY
