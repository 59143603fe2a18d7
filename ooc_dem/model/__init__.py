"""The model: the scenario (schema, validation, built-ins), the particle state, its
epoch format (checkpoint), hashes and the domain decomposition. Knows nothing of
engines or the application."""
