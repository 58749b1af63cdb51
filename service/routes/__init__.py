"""HTTP routes: thin adapters from requests to :mod:`service.clips` and :mod:`service.jobs`."""
