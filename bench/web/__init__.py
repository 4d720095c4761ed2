"""The web station (``bench serve``): the catalogue of runs, run pages with decimated plots, live
runs controlled from the browser, and runs started from the procedure library (docs/web.md).

Modules: :mod:`~bench.web.paths` (run ids and procedure names mapped to files inside their
directories only), :mod:`~bench.web.decimate` (per-pixel min/max of a stream over a time range),
:mod:`~bench.web.pages` (run and runs data as JSON), :mod:`~bench.web.live` (runs started here:
runner thread, answers from the page, controls), :mod:`~bench.web.launch` (procedure library, plan,
validation, start), :mod:`~bench.web.app` (the Starlette application and its access rules),
:mod:`~bench.web.requests` (every request value typed strictly), :mod:`~bench.web.guards` (Host and
body size, before any endpoint), :mod:`~bench.web.server` (uvicorn with bounded request reads, proxy
headers only from trusted proxies), :mod:`~bench.web.runs_index` (the runs table read without
writing the catalogue), :mod:`~bench.web.credentials` (no run file holding a credential is served).
"""
