"""Monte Carlo campaigns (issue 27; docs/montecarlo.md): ``skyfix montecarlo CAMPAIGN.toml``.

- :mod:`skyfix.montecarlo.campaign` — the campaign file read into a checked :class:`Campaign`.
- :mod:`skyfix.montecarlo.trials` — one trial (simulate → solve → compare), a pure function of
  (campaign, trial index), at the centroid or the image level.
- :mod:`skyfix.montecarlo.engine` — the batches run on Dask, kept on disk, resumed.
- :mod:`skyfix.montecarlo.results` — the Parquet rows, the summary, the plots.
- :mod:`skyfix.montecarlo.budget` — the attitude error predicted from centroid noise and geometry.

The command is :mod:`skyfix.cli.montecarlo`.

Nothing is imported here: dask and pyarrow load only with a campaign.
"""
