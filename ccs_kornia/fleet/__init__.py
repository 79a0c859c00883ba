"""Many calibrations on Lightning (``calibrate-many``): the predict loop over image sets and the JSON Lines shards
that processes write and merge.
"""
