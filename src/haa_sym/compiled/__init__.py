"""Generated and compiled code (layer 4): the layout contract between code generation and
runtime, loading and checking `generated/`, compiling a user actuator's plant, caches."""
