"""A study run on the rig (`mantis study`): its plan trial by trial on a rig brought up for it or
already running (`session`, `rig`, `runner`), its record `study.csv` (`record`), each bag
measured (`measure`) and judged against the twin's forecast by a worker process (`analyst`),
the videos attached (`attach`) and the report (`report`). The science of it is in
mantis_sim/studies/rig_study."""
