"""Thin glue, one module per command verb: read inputs, call the library, publish the outputs."""
