"""Offline training of the vessel detector from labels generated from the vessel's GPS (``./vessel detect train``).

Layered like the rest of the project: :mod:`.labels` and :mod:`.augment` need only numpy and OpenCV; :mod:`.model`,
:mod:`.loss` and :mod:`.trainer` need the training extra (PyTorch and onnx2torch, ``./vessel setup --train``).
"""
