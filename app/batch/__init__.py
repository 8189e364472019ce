"""``solarnav batch``: many logs processed on a Dask cluster, their summary and per-vehicle history."""
