"""HTML reports of a calibration and of a rig: figures, quality pages, one ``index.html`` per report.
"""
