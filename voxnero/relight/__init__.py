"""Relighting: load an exported asset, choose cameras, path-trace it under an HDR env map."""
