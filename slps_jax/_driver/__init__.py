"""The driver: checks a run against its system and method (`plan`), owns the time loop
(`integrate`: `integrate`, `simulate`; `stream`: `ensemble_statistics`), the retry of failing
steps (`retry`), the failure report (`failures`) and the sharding of samples (`sharding`)."""
