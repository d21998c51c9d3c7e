"""The crane as data: the TOML spec (validated), the index layout, physical parameters, gains, the MJCF
model, the generator's fingerprint, where files live. Imports nothing else of the package."""
