"""The LightningDataModules of training: seeded, rendered on the fly (detector, distortion network, calibration sets);
training, validation and benchmark seeds never overlap (datamodule).
"""
