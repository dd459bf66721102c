"""Recording and what reads recordings.

MCAP I/O, CDR, the recorder, replay, reindex, the report and the paper's figures.
"""
