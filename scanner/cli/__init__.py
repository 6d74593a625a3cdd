"""The `scanner` command line: the parser, shared argument types and the dispatch to each
command."""
