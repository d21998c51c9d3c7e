"""The process around the crane: Ctrl-C held back or raised, the helper libraries' warnings kept off a user's terminal,
the optional extras, where files live (the examples, the cache). Imports nothing else of the package."""
