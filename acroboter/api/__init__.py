"""The library face: `Crane` (spec -> compiled model -> controllers -> simulate -> Result)."""
