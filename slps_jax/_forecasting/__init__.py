"""The forecast-and-assimilation workflow built on the driver: a data-driven transport noise
fitted from a fine run (`transport_fit`), ensemble forecasts and their verification scores
(`verification`, `scores`), and the particle filter (`assimilation`: the filter for any
forecast; `particle_filter`: with the library's integrators as the forecast)."""
