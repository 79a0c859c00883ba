"""The commands of ``python -m ccs_kornia`` (parser and dispatch in :mod:`ccs_kornia.cli`), one module each.

``detect``, ``calibrate``, ``undistort``, ``calibrate_many`` and ``demo`` each expose ``run(args) -> exit status``;
:mod:`~ccs_kornia.commands._common` holds what they share (``UserError``, messages, devices, streaming detection).
"""
