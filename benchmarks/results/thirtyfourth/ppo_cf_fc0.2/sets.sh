SETS=(--set "objects.train=[cube,frustum]" --set "objects.ood=[]" --set "objects.heldout_pairs=[]"
  --set scenes.singles=false --set scenes.many=false
  --set "scenes.per_combination={train: 10, Pl: 7, Com: 0, Geo: 0, many: 0}"
  --set "synthesis.splits=[train,Pl]" --set "synthesis.max_scenes_per_combination={train: 10, Pl: 7}"
  --set synthesis.optimizer.fc_friction=0.2
  --set specialists.clustering.mode=combination --set specialists.max_bins=1)
X=(--set specialists.ppo.std_mode=independent --set specialists.ppo.reward_scale=0.1
   --set specialists.ppo.critic_warmup_iterations=10 --set specialists.ppo.target_kl=0.02
   --set specialists.ppo.normalizer_frozen_after=10)
# The lift env of every run that sources this file (thirty-fourth to fortieth sessions): the grasp closure pressed
# every near link and the finger pads had no torsional friction, the defaults until the forty-first session. A lift
# probe of those sessions (benchmarks.lift_failures with "${SETS[@]}") needs "${OLD_LIFT[@]}" for its old baseline.
# Options given after X (the fortieth session's) still win.
OLD_LIFT=(--set lift.closure_links=all --set lift.hand_spinning_friction=0)
X+=("${OLD_LIFT[@]}")
