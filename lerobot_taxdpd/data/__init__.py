"""The data layer: the dataset schema, input checks, the atomic dataset writer and dataset scaling."""
