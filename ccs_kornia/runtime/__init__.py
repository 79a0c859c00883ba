"""The process around the stages: lazy package exports, worker threads, the allocator's settings, stage timing, and
the errors a user can fix with the exit statuses they give.

The bottom layer: it imports nothing else of the package, and every layer may import it.
"""
