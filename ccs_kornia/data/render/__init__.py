"""The image renderer with exact ground truth: area-sampled chessboards (renderer), the lens models and their exact
inverses (lens, fisheye), marks in the light squares, the camera's optics and lighting, photometric degradations and
backgrounds (augment).
"""
