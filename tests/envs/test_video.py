import cv2
import numpy as np
import pytest
from env_helpers import small_parallel_env

from uav_struct_env.envs.video import record_rollout, write_video


@pytest.mark.parametrize("suffix", [".mp4", ".gif"])
def test_record_rollout(tmp_path, suffix):
    env = small_parallel_env(render_mode="rgb_array", landmark_sets=())
    path = record_rollout(
        env, tmp_path / f"rollout{suffix}", n_steps=3, seed=0, options={"viewpoint": 0}
    )
    assert path.exists() and path.stat().st_size > 1000
    if suffix == ".mp4":
        cap = cv2.VideoCapture(str(path))
        n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        cap.release()
        assert n == 4
    env.close()


def test_write_video_errors(tmp_path):
    frame = np.zeros((10, 10, 3), np.uint8)
    with pytest.raises(ValueError, match="must end in .mp4, .avi or .gif"):
        write_video([frame], tmp_path / "x.png")
    with pytest.raises(ValueError, match="at least one frame"):
        write_video([], tmp_path / "x.gif")
    with pytest.raises(ValueError, match="frame 1 must be uint8"):
        write_video([frame, np.zeros((5, 10, 3), np.uint8)], tmp_path / "x.gif")
    env = small_parallel_env(landmark_sets=())
    with pytest.raises(ValueError, match="render_mode='rgb_array'"):
        record_rollout(env, tmp_path / "x.gif")
