"""The Delta ASDA-A3 as data: parameter table, DI/DO codes, alarm table, object dictionary.

Read by the model, the faces, the drivers and the plans alike. Every module but `eds` is pure
(no bus library); `eds` writes the object dictionary as an EDS with `canopen`.
"""
