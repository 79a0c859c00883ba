"""Chessboard detection stages (being populated by the restructure, issue 13)."""
