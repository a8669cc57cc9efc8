"""Tasks: what a run trains the decoder's output for (its target, loss, metrics, model selection, pictures).

A task is a plugin kind like the encoders and decoders (``optoenc tasks`` lists them). The training
module stays generic: it feeds the decoder's output and the batch's target to :meth:`Task.loss` and
:meth:`Task.update_metrics`, and the run selects its best checkpoint on :attr:`Task.monitor`.

* ``classification`` (the default): the decoder emits logits, the target is the label, the loss
  cross-entropy, the metric accuracy (``val_acc``, selected at its highest).
* ``reconstruction``: the decoder emits the scene, the target is the scene itself, the loss
  ``task.loss`` (``mse`` or ``l1``), the metrics PSNR and the standard SSIM of the reconstruction clipped
  to the scenes' range [0, 1] (:mod:`optoenc.metrics`; ``val_psnr``, ``val_ssim``), selected at the
  lowest ``val_loss``.
"""

from .base import DECODER_OUTPUTS, TASK_FEATURES, Task, TaskConfig
from .builtin import Classification, Reconstruction, ReconstructionConfig

__all__ = ["TaskConfig", "Task", "Classification", "ReconstructionConfig", "Reconstruction", "DECODER_OUTPUTS", "TASK_FEATURES"]
