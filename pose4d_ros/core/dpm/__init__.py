"""The 4D-DPM part detector: Yang & Ramanan's flexible mixture of parts with a depth channel.

- `model`: the `PartModel` dataclass, `save_model`, `load_model`.
- `infer`: `Detector`, `detect`, `Pose`, `SearchConfig` (exact inference by dynamic programming).
- `dt`: generalized distance transforms.

Training lives in `training.dpm`: part types by k-means, per-part templates, the structural SVM
(dual coordinate descent) with hard-negative mining.
"""

from pose4d_ros.core.dpm.infer import Detector, Pose, SearchConfig, detect
from pose4d_ros.core.dpm.model import PartModel, load_model, save_model

__all__ = ['Detector', 'PartModel', 'Pose', 'SearchConfig', 'detect', 'load_model',
           'save_model']
