"""The commands of ``python -m ccs_kornia`` (parser and dispatch in :mod:`ccs_kornia.cli`), one module each.

Each command module exposes ``run(args) -> exit status``. What several commands share sits in private modules beside
them, one concern each: ``_printing`` (messages on stderr), ``_devices`` (``--device``), ``_output_paths`` (output
files and folders checked before any work), ``_inputs`` (the images named), ``_boards`` (the board arguments and their
records), ``_factories`` (the detector and pipeline of the arguments), ``_run`` (the pipeline's run on the views, with
a progress bar; one camera to its record), ``_wrong_board`` (a wrong board named from the images), ``_messages``
(results in words), ``_stereo_pair`` (``--pair``), ``_video`` (recordings) and ``_selection`` (the frame selection).
No command imports another: what two of them share moves to one of these, or below them (``pipeline/``,
``outputs/``).
"""
