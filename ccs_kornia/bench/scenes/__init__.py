"""The benchmark's inputs: seeded rendered scenes and the corner bookkeeping against their truth (scenes), synthetic
Kannala-Brandt cameras and board views (fisheye_data).
"""
