"""The benchmark's report: the markdown and the RMS box plot (report), the tables of the speed and wild sections
(speed_report, wild_report).
"""
