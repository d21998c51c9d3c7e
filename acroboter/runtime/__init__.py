"""Generated C made callable: compile it into the cache, bind it with ctypes (shapes and hashes checked),
find or generate a spec's sources, and the casadi.Function reference. Only cache.py and casadi_backend.py
may call the code generator."""
