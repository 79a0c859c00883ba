"""Synthetic data with exact ground truth: the image renderer (render/), what it renders (scenes/), recordings of a
hand-held board (recordings/) and the LightningDataModules of training (datamodules/). It depends on
:mod:`ccs_kornia.geometry` only, never on the stages it is used to test.
"""
