"""What is rendered, with exact ground truth: calibration sets and training scenes and their random distortions and
poses (sampling), chessboards in the wild, board-free images (distractors), marker boards (marker_views), the corner
network's heatmap targets; camera rigs (rig) and robot arms (robots) at the level of their corners.
"""
