"""Shipped, trained part models (.npz) and their training notes."""
