"""``hbake batch``: many meshes into bundles, incrementally and failure-tolerant.

jobs (the plan, the job runner, the batch manifest), executors (where jobs run: this
machine or a Dask cluster).
"""
