"""The crane as data: the TOML spec (validated), the index layout, physical parameters, the controller's parameters
and settings, the MJCF model, the generator's fingerprint, the package's C sources. Imports only acroboter.process."""
