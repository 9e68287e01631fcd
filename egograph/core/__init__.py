"""The bottom layer: records, units, errors and the config machinery; imports nothing else of egograph."""
