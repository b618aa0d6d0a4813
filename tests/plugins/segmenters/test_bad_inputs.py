"""The oracle segmenter without the ground truth it needs: a DataError saying what is missing and how to
get it (was a bare AssertionError)."""

from __future__ import annotations

import numpy as np
import pytest

from stratamap.core.errors import DataError
from stratamap.core.map.groundtruth import GroundTruth
from stratamap.core.map.sensors import CameraIntrinsics, RGBDFrame, SensorStream
from stratamap.core.stages import PipelineData
from stratamap.plugins.segmenters.oracle import OracleSegmenter


def data(ground_truth: GroundTruth | None, frames: int = 2) -> PipelineData:
    stream = SensorStream(
        name="seq",
        intrinsics=CameraIntrinsics(4, 3, 3.0, 3.0, 2.0, 1.5),
        frames=[
            RGBDFrame(k, 0.1 * k, np.zeros((3, 4, 3), np.uint8), np.ones((3, 4), np.float32)) for k in range(frames)
        ],
    )
    return PipelineData(stream=stream, ground_truth=ground_truth)


@pytest.mark.parametrize(
    "pipeline_data,message",
    [
        (
            lambda: data(None),
            r"oracle: no ground truth for 'seq': the oracle needs per-frame labels from a gt/ folder beside the "
            r"sequence .*`stratamap synth`",
        ),
        (lambda: data(GroundTruth()), r"oracle: the ground truth of 'seq' has no per-frame labels"),
        (lambda: data(None, frames=0), r"oracle: the source gave no camera frames"),
        (lambda: PipelineData(), r"oracle: the source gave no camera frames"),
    ],
)
def test_oracle_without_ground_truth(pipeline_data, message):
    with pytest.raises(DataError, match=message) as err:
        OracleSegmenter().run(pipeline_data())
    assert "\n" not in str(err.value)
