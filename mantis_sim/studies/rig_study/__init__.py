"""Studies on the rig: a plan of trials (factors, repeats, an order that keeps them apart from the
day's drift), each trial forecast by the twin at its conditions and judged as it lands, and the
effects the study's strikes resolve beside the twin's forecast of them.

No ROS here: the rig package runs a plan on a rig and hands each trial's measured values to
these modules (plan, forecast, judge, effects, figures)."""
