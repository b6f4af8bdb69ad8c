"""The Delta ASDA-A3 as data: parameter table, DI/DO codes, alarm table, object dictionary.

Read by the model, the faces, the drivers and the plans alike. `params`, `dio`, `alarms` and
`errors` are pure (no bus library); `od` builds the CANopen dictionary on `canopen`.
"""
