"""05: replay the bundled [Q17] flight-test records at the paper's target heights."""

from geoloc.io.records import load_records
from geoloc.sensors.camera import Camera
from geoloc.workflows.replay import replay_at_height, summary_table

records = load_records("assets/records/qiao2017_flight_tests.csv")
camera = Camera.from_toml("assets/cameras/qiao2017.toml")
print(summary_table(replay_at_height(records, camera, "paper_height_m")))
