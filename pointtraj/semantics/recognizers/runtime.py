"""CPU model runtimes: onnxruntime (:class:`_OnnxModel`) and LiteRT (:class:`_TfliteModel`).

Both share the pre-processing of :mod:`.processing` through their base :class:`_Model`.
"""

from __future__ import annotations

import os
from collections.abc import Sequence

import numpy as np

from ...errors import ValidationError, check_array
from .processing import _COLOR, _LAYOUT, _RESIZE, Preprocessing, _choice, prepare_input


class _Model:
    """A model runtime on the CPU with its pre-processing settings.

    The base of the onnxruntime and LiteRT wrappers: both validate the same pre-processing
    options into :attr:`pre` and run an image through :func:`prepare_input`. Subclasses load
    the model (:meth:`_load`), settle the input size and layout from it (:meth:`_input_geometry`)
    and run one input tensor (:meth:`_invoke`).

    Attributes
    ----------
    pre : Preprocessing
        The validated recipe.
    dtype : numpy dtype
        Dtype of the model's input tensor.
    output_names : list of str
        The model's outputs, in the order :meth:`run` returns them.
    """

    pre: Preprocessing
    dtype: type | np.dtype
    output_names: list[str]

    def __init__(
        self,
        model: str | os.PathLike,
        *,
        input_size: tuple[int, int] | None,
        resize: str,
        color: str,
        mean: Sequence[float],
        std: Sequence[float],
        scale: float,
        layout: str,
        pad_value: float,
        threads: int,
    ) -> None:
        self._load(model, threads)
        size, layout = self._input_geometry(model, input_size, _choice("layout", layout, _LAYOUT))
        w, h = (int(v) for v in size)
        if w <= 0 or h <= 0:
            raise ValidationError(f"input_size: expected positive (width, height), got {size}")
        self.pre = Preprocessing(
            size=(w, h),
            resize=_choice("resize", resize, _RESIZE),
            color=_choice("color", color, _COLOR),
            mean=tuple(float(v) for v in check_array("mean", mean, (3,))),
            std=tuple(float(v) for v in check_array("std", std, (3,))),
            scale=float(scale),
            layout=layout,
            pad_value=float(pad_value),
        )

    def _load(self, model: str | os.PathLike, threads: int) -> None:
        """Load ``model`` and set :attr:`dtype` and :attr:`output_names`."""
        raise NotImplementedError

    def _input_geometry(
        self, model: str | os.PathLike, input_size: tuple[int, int] | None, layout: str
    ) -> tuple[tuple[int, int], str]:
        """The input (width, height) and layout ("nchw" or "nhwc") from the requested ones
        (``input_size`` None and ``layout`` "auto" ask the model)."""
        raise NotImplementedError

    def _invoke(self, tensor: np.ndarray) -> list[np.ndarray]:
        """The model's outputs for one input tensor."""
        raise NotImplementedError

    def run(self, image: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
        """Pre-process and run one image.

        Parameters
        ----------
        image : (H, W, 3) uint8 ndarray
            RGB image.

        Returns
        -------
        outputs : list of ndarray
            The model's outputs, in :attr:`output_names` order.
        transform : (4,) float ndarray
            Image to model-input pixels, see :func:`prepare_input`.
        """
        tensor, transform = prepare_input(image, self.pre, self.dtype)
        return self._invoke(tensor), transform


class _OnnxModel(_Model):
    """An onnxruntime session on the CPU with pre-processing settings."""

    def _load(self, model: str | os.PathLike, threads: int) -> None:
        import onnxruntime as ort

        if not os.path.isfile(model):
            raise ValidationError(f"model: no such ONNX file {os.fspath(model)!r}")
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = threads
        opts.inter_op_num_threads = 1
        opts.log_severity_level = 3
        try:
            self.session = ort.InferenceSession(
                os.fspath(model), sess_options=opts, providers=["CPUExecutionProvider"]
            )
        except Exception as exc:  # onnxruntime raises its own exception types
            raise ValidationError(f"model: cannot load {os.fspath(model)!r}: {exc}") from None
        inp = self.session.get_inputs()[0]
        self.input_name = inp.name
        self.output_names = [o.name for o in self.session.get_outputs()]
        self.dtype = {"tensor(uint8)": np.uint8, "tensor(float16)": np.float16}.get(
            inp.type, np.float32
        )
        self._input_shape = list(inp.shape)

    def _input_geometry(
        self, model: str | os.PathLike, input_size: tuple[int, int] | None, layout: str
    ) -> tuple[tuple[int, int], str]:
        shape = self._input_shape
        if layout == "auto":
            layout = (
                "nhwc"
                if len(shape) == 4 and shape[3] in (1, 3) and shape[1] not in (3,)
                else "nchw"
            )
        if input_size is None:
            hw = shape[2:4] if layout == "nchw" else shape[1:3]
            if len(shape) != 4 or not all(isinstance(d, int) and d > 0 for d in hw):
                raise ValidationError(
                    f"input_size: the model's input {self.input_name!r} has shape {shape}; give "
                    "input_size=(width, height)"
                )
            input_size = (int(hw[1]), int(hw[0]))
        return input_size, layout

    def _invoke(self, tensor: np.ndarray) -> list[np.ndarray]:
        return self.session.run(None, {self.input_name: tensor})


def _litert_interpreter_class(user: str) -> type:
    """The LiteRT ``Interpreter`` class; ``user`` (who needs it) starts the error message.

    Raises
    ------
    ValidationError
        If the ``ai-edge-litert`` package is not installed.
    """
    try:
        from ai_edge_litert.interpreter import Interpreter
    except ImportError:
        raise ValidationError(
            f"{user} needs the LiteRT interpreter: pip install ai-edge-litert "
            "(or pointtraj[models])"
        ) from None
    return Interpreter


class _TfliteModel(_Model):
    """A LiteRT interpreter (TensorFlow Lite model) with pre-processing settings.

    TensorFlow Lite images are NHWC. A ``uint8`` input gets raw pixels (quantised models such
    as the Coral SSD detectors fold the normalisation into the input's quantisation), a
    ``float32`` input gets ``(pixel * scale - mean) / std``.
    """

    def _load(self, model: str | os.PathLike, threads: int) -> None:
        if not os.path.isfile(model):
            raise ValidationError(f"model: no such TFLite file {os.fspath(model)!r}")
        Interpreter = _litert_interpreter_class(f"model: running {os.fspath(model)!r}")
        try:
            self.interpreter = Interpreter(model_path=os.fspath(model), num_threads=threads)
            self.interpreter.allocate_tensors()
        except (ValueError, RuntimeError) as exc:
            raise ValidationError(f"model: cannot load {os.fspath(model)!r}: {exc}") from None
        inp = self.interpreter.get_input_details()[0]
        self.input_index = inp["index"]
        self.outputs = self.interpreter.get_output_details()
        self.output_names = [d["name"] for d in self.outputs]
        shape = [int(v) for v in inp["shape"]]
        if len(shape) != 4 or shape[0] != 1 or shape[3] != 3:
            raise ValidationError(
                f"model: {os.fspath(model)!r} has input shape {shape}; expected [1, h, w, 3]"
            )
        self.dtype = np.dtype(inp["dtype"])
        if self.dtype not in (np.dtype(np.uint8), np.dtype(np.float32)):
            raise ValidationError(
                f"model: {os.fspath(model)!r} has a {self.dtype} input; supported: uint8, float32"
            )
        self._input_shape = shape

    def _input_geometry(
        self, model: str | os.PathLike, input_size: tuple[int, int] | None, layout: str
    ) -> tuple[tuple[int, int], str]:
        if layout == "nchw":
            raise ValidationError("layout: TensorFlow Lite models take NHWC images, not 'nchw'")
        size = (self._input_shape[2], self._input_shape[1])
        if input_size is not None and tuple(int(v) for v in input_size) != size:
            raise ValidationError(
                f"input_size: {os.fspath(model)!r} has a fixed {size[0]}x{size[1]} input, got "
                f"{tuple(input_size)}"
            )
        return size, "nhwc"

    def _invoke(self, tensor: np.ndarray) -> list[np.ndarray]:
        self.interpreter.set_tensor(self.input_index, tensor)
        self.interpreter.invoke()
        return [self.interpreter.get_tensor(d["index"]).copy() for d in self.outputs]
