%% @doc The operator's facade: what the HTTP API (evatar_web_api) and the
%% release's commands (bin/evatar status, pairings, ...) show and do, as
%% plain functions returning JSON-ready maps (atom or binary keys, binary,
%% number, boolean, null or atom values, lists; no pids or tuples).
%% docs/api.md gives every shape. A refusal is `{error, error()}': a code
%% from a fixed set, the field of the input at fault (or null), a sentence,
%% and the HTTP status that fits. Input is checked here, field by field,
%% before anything reaches a pairing; no atom is made from it. Pairing
%% options are then checked by evatar:check_pairing_opts/1 (the
%% configuration file's check). Changing or rotating a pairing's options
%% deletes and re-creates it (a pairing takes its options when it
%% starts); an MQTT Avatar's description override restarts it through
%% mqtt_avatar:reconfigure/2.
-module(evatar_ops).

-export([cluster/0, local_instances/0, pairings/0, pairing/1, bindings/1,
         create/2, change/2, delete/1, rotate/2,
         mqtt_avatars/0, mqtt_avatar/1, override_description/2, problems/1,
         wot_avatars/0, wot_problems/1]).

-export_type([error/0]).

-type error() :: #{error := binary(), field := binary() | null, message := binary(),
                   status := 400..599}.

-define(RPC_TIMEOUT, 5000).
%% Options a request may set, and how each is checked.
-define(INT_OPTS, [<<"join_timeout">>, <<"feedback_timeout">>, <<"resume_timeout">>]).
-define(POS_OPTS, [<<"max_avatars">>, <<"dedup_window">>, <<"max_unacked_out">>,
                   <<"max_open_requests">>, <<"max_consumes">>, <<"max_id_length">>,
                   <<"max_binding_report">>]).
-define(CRED_OPTS, [<<"agent_credential">>, <<"avatar_credential">>]).
-define(OTHER_OPTS, [<<"identities">>, <<"unlisted_ids">>, <<"standby_node">>]).
-define(MAX_ID, 128).
-define(RECREATE_WAIT_MS, 10000).

%% ---------------------------------------------------------------------------
%% Cluster
%% ---------------------------------------------------------------------------

%% @doc The cluster as this node sees it: every configured node (up or
%% suspected), whether a majority is heard, and per pairing its active's
%% node, its standby's node, its epoch and whether the standby is synced.
-spec cluster() -> map().
cluster() ->
    #{configured := Configured, up := Up, suspected := Suspected, quorum := Quorum} =
        evatar:cluster_status(),
    Nodes = lists:usort(Configured ++ Up ++ Suspected),
    Instances = instances(Up),
    #{node => node(),
      quorum => Quorum,
      nodes => [#{node => N,
                  self => N =:= node(),
                  configured => lists:member(N, Configured),
                  up => lists:member(N, Up),
                  suspected => lists:member(N, Suspected)} || N <- Nodes],
      pairings => [pairing_ha(Id, [I || {_, #{id := Id1}} = I <- Instances, Id1 =:= Id])
                   || Id <- lists:usort([Id || {_, #{id := Id}} <- Instances]
                                        ++ evatar:catalogued())]}.

%% Every instance on the alive nodes, one call per node.
instances(Up) ->
    Nodes = lists:usort([node() | Up]),
    Results = erpc:multicall(Nodes, ?MODULE, local_instances, [], ?RPC_TIMEOUT),
    [{N, I} || {N, {ok, Is}} <- lists:zip(Nodes, Results), I <- Is].

%% @doc This node's instances of pairings with their high-availability
%% state (for cluster/0, called on every alive node).
-spec local_instances() -> [map()].
local_instances() ->
    [instance(Id, evatar:ha_status(Id)) || #{id := Id} <- evatar:pairings()].

instance(Id, {ok, #{role := Role, epoch := Epoch, standby_node := SN, synced := Synced}}) ->
    #{id => Id, role => Role, epoch => Epoch, node => node(), standby_node => null_if_undefined(SN),
      synced => Synced};
instance(Id, {error, Why}) ->
    #{id => Id, role => Why, epoch => null, node => node(), standby_node => null, synced => false}.

pairing_ha(Id, Instances) ->
    Actives = [I || {_, #{role := active} = I} <- Instances],
    Standbys = [N || {N, #{role := standby}} <- Instances],
    Active = case Actives of
                 [] -> #{};
                 _ -> lists:last(lists:sort(fun(#{epoch := A}, #{epoch := B}) -> A =< B end, Actives))
             end,
    #{id => Id,
      active => maps:get(node, Active, null),
      standby => case {maps:get(standby_node, Active, null), Standbys} of
                     {null, [S | _]} -> S;
                     {S, _} -> S
                 end,
      epoch => maps:get(epoch, Active, lists:max([0 | [E || {_, #{epoch := E}} <- Instances,
                                                             is_integer(E)]])),
      synced => maps:get(synced, Active, false),
      instances => [#{node => N, role => R, epoch => E} || {N, #{role := R, epoch := E}} <- Instances]}.

%% ---------------------------------------------------------------------------
%% Pairings
%% ---------------------------------------------------------------------------

%% @doc Every pairing instance of this node, by id, with its state and
%% counts; one too busy to answer has `state' unavailable.
-spec pairings() -> [map()].
pairings() ->
    [summary(S) || S <- evatar:pairings()].

summary(S) ->
    Keys = [id, state, role, epoch, agent, avatars, registered, bound, unbound, pending],
    maps:from_list([{K, null_if_undefined(maps:get(K, S, null))} || K <- Keys]).

%% @doc One pairing of this node: its summary, high-availability state,
%% options (credentials only said to be set), entities and counters.
-spec pairing(binary()) -> {ok, map()} | {error, error()}.
pairing(Id) ->
    case [S || #{id := Id1} = S <- evatar:pairings(), Id1 =:= Id] of
        [] ->
            not_found(Id);
        [S | _] ->
            case {evatar:registry(Id), evatar:stats(Id), evatar:ha_status(Id)} of
                {{ok, Registry}, {ok, Stats}, {ok, Ha}} ->
                    {ok, (summary(S))#{ha => ha(Ha),
                                       options => options(Id),
                                       entities => [entity(E) || E <- Registry],
                                       stats => Stats}};
                _ ->
                    busy(Id)
            end
    end.

ha(#{role := Role, epoch := Epoch, standby_node := SN, synced := Synced, version := V}) ->
    #{role => Role, epoch => Epoch, standby_node => null_if_undefined(SN), synced => Synced,
      version => V}.

options(Id) ->
    case evatar:stored_options(Id) of
        {ok, Config} ->
            maps:map(fun(K, _) when K =:= agent_credential; K =:= avatar_credential -> <<"set">>;
                        (identities, Is) ->
                             [#{entity => E, role => R,
                                credential => maps:is_key(credential, I),
                                cert_sha256 => maps:get(cert_sha256, I, null)}
                              || #{entity := E, role := R} = I <- Is];
                        (_, V) -> V
                     end, Config);
        {error, not_found} ->
            #{}
    end.

%% An entity's state: `connected' (joined, no description yet),
%% `described' (registered its description), `detached' (its connection
%% went; the pairing keeps it for a resume).
entity(#{entity := Id, role := Role, registered := Registered, attached := Attached,
         description := D} = E) ->
    #{entity => Id, role => Role,
      state => if not Attached -> detached;
                  Registered -> described;
                  true -> connected
               end,
      connected => Attached, described => Registered, detached => not Attached,
      delivered => maps:get(delivered, E, 0), unacked => maps:get(unacked, E, 0),
      components => case D of
                        undefined -> [];
                        #{components := Cs} -> [component(C) || C <- Cs]
                    end}.

component(#{id := C, services := S, consumes := U}) ->
    #{id => C, services => [entry(X) || X <- S], consumes => [entry(X) || X <- U]}.

entry(#{category := Cat, type := T, parameters := Ps}) ->
    #{category => Cat, type => T, parameters => params(Ps)}.

params(Ps) -> [#{name => N, value => V} || {N, V} <- Ps].

%% @doc A pairing's Body Mapping Registry as a graph: the VA's components
%% on one side, the Avatars' on the other, the bound edges (consumer to
%% provider, with the service), and every unbound entry with its reason and,
%% for each candidate provider, the parameters it did not match.
-spec bindings(binary()) -> {ok, map()} | {error, error()}.
bindings(Id) ->
    case {evatar:bindings(Id), evatar:registry(Id)} of
        {{ok, #{bound := Bound, unbound := Unbound}}, {ok, Registry}} ->
            Descriptions = [D || #{description := D} <- Registry, D =/= undefined],
            Side = fun(Role) ->
                           [#{entity => E, state => maps:get(state, entity(R)),
                              components => [component(C) || #{components := Cs} <- [D], C <- Cs]}
                            || #{entity := E, role := Role1, description := D} = R <- Registry,
                               Role1 =:= Role]
                   end,
            {ok, #{pairing => Id,
                   agents => Side(agent),
                   avatars => Side(avatar),
                   bound => [#{consumer => endpoint(C), provider => endpoint(P), category => Cat,
                               type => T, score => S, candidates => N}
                             || #{consumer := C, provider := P, category := Cat, type := T,
                                  score := S, candidates := N} <- Bound],
                   unbound => [unbound(U, Index) || Index <- [evatar_web_explain:index(Descriptions)],
                                                    U <- Unbound]}};
        {{error, not_found}, _} -> not_found(Id);
        {_, {error, not_found}} -> not_found(Id);
        _ -> busy(Id)
    end.

unbound(#{consumer := C, category := Cat, type := T, reason := R} = U, Index) ->
    {Candidates, More} = evatar_web_explain:explain(U, Index),
    #{consumer => endpoint(C), category => Cat, type => T,
      reason => case R of
                    no_provider -> <<"NoProvider">>;
                    parameters_mismatch -> <<"ParametersMismatch">>
                end,
      candidates => [#{provider => endpoint(P),
                       mismatches => [#{name => N, wanted => W, offered => O} || {N, W, O} <- F]}
                     || #{provider := P, failed := F} <- Candidates],
      more_candidates => More}.

endpoint(#{entity := E, component := C}) -> #{entity => E, component => C}.

%% @doc Creates a pairing from JSON-decoded options (binary keys): each is
%% checked and named in the error, then evatar checks them as a whole.
%% Returns the new pairing (pairing/1).
-spec create(term(), term()) -> {ok, map()} | {error, error()}.
create(Id, Body) ->
    case {pairing_id(Id), pairing_opts(Body)} of
        {ok, {ok, Opts}} ->
            case evatar:create_pairing(Id, Opts) of
                {ok, _} -> created(Id);
                {error, Why} -> refused(Id, Why)
            end;
        {{error, _} = Error, _} -> Error;
        {_, {error, _} = Error} -> Error
    end.

created(Id) ->
    case pairing(Id) of
        {ok, P} -> {ok, P};
        {error, _} -> {ok, #{id => Id}}
    end.

%% @doc Changes a pairing's options: the given keys replace the stored
%% ones (credentials are hashed; omitted keys stay). A pairing cannot take
%% new options while it runs, so it is deleted and created again: its
%% entities are dropped (`pairing_deleted') and join again, the new options
%% applying to them. The new options are checked before anything stops.
%% The body holds options only: an `id' (even the pairing's own) is
%% refused, as a pairing cannot be renamed.
-spec change(binary(), term()) -> {ok, map()} | {error, error()}.
change(_Id, #{<<"id">> := _}) ->
    err(400, <<"bad_request">>, <<"id">>,
        <<"id is not an option: the pairing is the one of the path, and cannot be renamed "
          "(delete it and create one with the new id)">>);
change(Id, Body) ->
    case {evatar:stored_options(Id), pairing_opts(Body)} of
        {{error, not_found}, _} -> not_found(Id);
        {_, {error, _} = Error} -> Error;
        {{ok, Old}, {ok, New}} -> replace(Id, maps:merge(Old, New))
    end.

replace(Id, Opts) ->
    case evatar:check_pairing_opts(Opts) of
        ok ->
            case evatar:delete_pairing(Id) of
                ok -> recreate(Id, Opts, erlang:monotonic_time(millisecond) + ?RECREATE_WAIT_MS);
                {error, Why} -> refused(Id, Why)
            end;
        {error, Why} ->
            refused(Id, Why)
    end.

%% The old instances go (the standby's node learns the deletion); until
%% then the id still exists elsewhere.
recreate(Id, Opts, Deadline) ->
    case evatar:create_pairing(Id, Opts) of
        {ok, _} ->
            created(Id);
        {error, already_exists} ->
            case erlang:monotonic_time(millisecond) < Deadline of
                true -> timer:sleep(100), recreate(Id, Opts, Deadline);
                false -> err(503, <<"busy">>, null,
                             <<"the pairing was deleted but its old instances did not go in time; "
                               "create it again">>)
            end;
        {error, Why} ->
            refused(Id, Why)
    end.

%% What evatar's refusal of a change to pairing Id says over HTTP
%% (docs/api.md, the error table).
refused(_Id, already_exists) ->
    err(409, <<"already_exists">>, <<"id">>, <<"a pairing with this id exists in the cluster">>);
refused(_Id, {disk_full, Dir}) -> disk_full(Dir);
refused(_Id, no_majority) -> no_majority();
refused(_Id, {bad_option, Bad}) -> bad_option(Bad);
refused(Id, not_found) -> not_found(Id);
refused(Id, busy) -> busy(Id).

%% A change this node cannot write: 507 Insufficient Storage.
disk_full(Dir) ->
    err(507, <<"disk_full">>, null,
        iolist_to_binary(["this node's data directory ", Dir, " is full: nothing was changed; "
                          "free space there, or ask another node"])).

%% A change this node may not make: it does not hear a majority of the
%% cluster (evatar_catalogue_rules:may_change/2).
no_majority() ->
    err(503, <<"no_majority">>, null,
        <<"this node does not hear a majority of the cluster's nodes (a partition, or most "
          "nodes down): nothing was changed; ask a node of the majority">>).

%% @doc Deletes a pairing in the whole cluster.
-spec delete(binary()) -> ok | {error, error()}.
delete(Id) ->
    case evatar:delete_pairing(Id) of
        ok -> ok;
        {error, Why} -> refused(Id, Why)
    end.

%% @doc Rotates one credential of a pairing: `{"role": "agent"|"avatar"}'
%% (a role credential) or `{"entity": Id}' (that identity's), to
%% `credential' when given, else to a new random one, returned once in
%% the answer (`credential'). Like change/2, the pairing restarts.
-spec rotate(binary(), term()) -> {ok, map()} | {error, error()}.
rotate(Id, Body) when is_map(Body) ->
    case {evatar:stored_options(Id), new_credential(Body)} of
        {{error, not_found}, _} ->
            not_found(Id);
        {_, {error, _} = Error} ->
            Error;
        {{ok, Old}, {ok, Secret, Generated}} ->
            case {rotated(Old, Body, Secret), Generated} of
                {{ok, Opts}, true} -> with_secret(replace(Id, Opts), Secret);
                {{ok, Opts}, false} -> replace(Id, Opts);
                {{error, _} = Error, _} -> Error
            end
    end;
rotate(_Id, _Body) ->
    err(400, <<"bad_request">>, null, <<"the body must be a JSON object">>).

%% A secret the node made is shown once, in the answer.
with_secret({ok, P}, Secret) -> {ok, P#{credential => Secret}};
with_secret(Error, _Secret) -> Error.

new_credential(#{<<"credential">> := C}) ->
    case credential(C) of
        ok -> {ok, C, false};
        {error, Why} -> err(400, <<"bad_request">>, <<"credential">>, Why)
    end;
new_credential(_) ->
    %% 192 random bits, as 48 hex digits: safe in any shell or file.
    {ok, string:lowercase(binary:encode_hex(crypto:strong_rand_bytes(24))), true}.

rotated(Old, #{<<"role">> := <<"agent">>} = B, Secret) when not is_map_key(<<"entity">>, B) ->
    {ok, Old#{agent_credential => Secret}};
rotated(Old, #{<<"role">> := <<"avatar">>} = B, Secret) when not is_map_key(<<"entity">>, B) ->
    {ok, Old#{avatar_credential => Secret}};
rotated(_Old, #{<<"role">> := _} = B, _) when not is_map_key(<<"entity">>, B) ->
    err(400, <<"bad_request">>, <<"role">>, <<"must be \"agent\" or \"avatar\"">>);
rotated(Old, #{<<"entity">> := E} = B, Secret) when is_binary(E), not is_map_key(<<"role">>, B) ->
    Is = maps:get(identities, Old, []),
    case [I || #{entity := E1} = I <- Is, E1 =:= E] of
        [] -> err(404, <<"not_found">>, <<"entity">>, <<"the pairing lists no identity with this entity">>);
        _ -> {ok, Old#{identities => [case I of
                                          #{entity := E} -> (maps:remove(cert_sha256, I))#{credential => Secret};
                                          _ -> I
                                      end || I <- Is]}}
    end;
rotated(_Old, _B, _) ->
    err(400, <<"bad_request">>, <<"role">>,
        <<"give either role (\"agent\" or \"avatar\") or entity (an identity's entity id)">>).

%% ---------------------------------------------------------------------------
%% Checks of input (JSON-decoded: binary keys, binaries, numbers, ...)
%% ---------------------------------------------------------------------------

%% Lengths are in characters (code points), as JSON Schema's minLength and
%% maxLength in priv/openapi.json count them.
pairing_id(Id) when is_binary(Id) ->
    case chars(Id) of
        N when is_integer(N), N >= 1, N =< ?MAX_ID -> ok;
        N when is_integer(N) -> id_length();
        _ -> err(400, <<"bad_request">>, <<"id">>, <<"must be UTF-8 text">>)
    end;
pairing_id(_) ->
    id_length().

id_length() ->
    err(400, <<"bad_request">>, <<"id">>,
        iolist_to_binary(io_lib:format("must be text of 1 to ~b characters", [?MAX_ID]))).

%% The number of characters of UTF-8 text, or `invalid'.
chars(Bin) ->
    case unicode:characters_to_list(Bin) of
        L when is_list(L) -> length(L);
        _ -> invalid
    end.

pairing_opts(Body) when is_map(Body) ->
    Known = ?INT_OPTS ++ ?POS_OPTS ++ ?CRED_OPTS ++ ?OTHER_OPTS,
    case [K || K <- maps:keys(Body), not lists:member(K, Known), K =/= <<"id">>] of
        [] -> fold_opts(maps:to_list(maps:remove(<<"id">>, Body)), #{});
        [K | _] -> err(400, <<"bad_request">>, K,
                       iolist_to_binary(["unknown option (known: ", lists:join(", ", Known), ")"]))
    end;
pairing_opts(_) ->
    err(400, <<"bad_request">>, null, <<"the body must be a JSON object">>).

fold_opts([], Acc) ->
    {ok, Acc};
fold_opts([{K, V} | Rest], Acc) ->
    case opt(K, V) of
        {ok, Key, Value} -> fold_opts(Rest, Acc#{Key => Value});
        %% Well formed, naming something that is not there (as rotate's entity).
        {error, not_found, Why} -> err(404, <<"not_found">>, K, Why);
        {error, Why} -> err(400, <<"bad_request">>, K, Why)
    end.

opt(K, V) ->
    case {lists:member(K, ?INT_OPTS), lists:member(K, ?POS_OPTS), lists:member(K, ?CRED_OPTS)} of
        {Ms, Count, _} when Ms; Count ->
            Key = binary_to_existing_atom(K),
            case in_range(Key, V) of
                true -> {ok, Key, V};
                false -> {error, range_message(Key)}
            end;
        {_, _, true} ->
            case credential(V) of
                ok -> {ok, binary_to_existing_atom(K), V};
                Error -> Error
            end;
        _ -> other_opt(K, V)
    end.

other_opt(<<"unlisted_ids">>, <<"refuse">>) -> {ok, unlisted_ids, refuse};
other_opt(<<"unlisted_ids">>, <<"role_credential">>) -> {ok, unlisted_ids, role_credential};
other_opt(<<"unlisted_ids">>, _) -> {error, <<"must be \"refuse\" or \"role_credential\"">>};
other_opt(<<"standby_node">>, N) when is_binary(N) ->
    %% Only a node of the cluster: its atom exists already.
    case [C || C <- cluster_nodes(), atom_to_binary(C) =:= N] of
        [Node | _] -> {ok, standby_node, Node};
        [] -> {error, not_found, <<"no such node in the cluster (GET /api/cluster lists them)">>}
    end;
other_opt(<<"standby_node">>, _) -> {error, <<"must be a node name (text)">>};
other_opt(<<"identities">>, Is) when is_list(Is) ->
    identities(Is, 0, []);
other_opt(<<"identities">>, _) -> {error, <<"must be a list of {\"entity\", \"role\", \"credential\"}">>}.

%% evatar's ranges (evatar:pairing_option_ranges/0): one table for the
%% API, the configuration file and evatar:create_pairing/2.
in_range(Key, V) ->
    {Min, Max} = maps:get(Key, evatar:pairing_option_ranges()),
    is_integer(V) andalso V >= Min andalso V =< Max.

range_message(Key) ->
    {Min, Max} = maps:get(Key, evatar:pairing_option_ranges()),
    Unit = case lists:member(atom_to_binary(Key), ?INT_OPTS) of
               true -> " (milliseconds)";
               false -> ""
           end,
    iolist_to_binary(io_lib:format("must be an integer from ~b to ~b~ts", [Min, Max, Unit])).

cluster_nodes() ->
    #{configured := C, up := U} = evatar:cluster_status(),
    lists:usort([node() | C ++ U]).

identities([], _, Acc) ->
    {ok, identities, lists:reverse(Acc)};
identities([I | Rest], N, Acc) when is_map(I) ->
    Where = fun(Why) -> {error, iolist_to_binary(io_lib:format("entry ~b: ~ts", [N, Why]))} end,
    Known = [<<"entity">>, <<"role">>, <<"credential">>, <<"cert_sha256">>],
    case {[K || K <- maps:keys(I), not lists:member(K, Known)], I} of
        {[K | _], _} -> Where(["unknown key ", K, " (known: entity, role, credential, cert_sha256)"]);
        {[], #{<<"entity">> := E}} when not is_binary(E); E =:= <<>> -> Where("entity must be non-empty text");
        {[], #{<<"role">> := R}} when R =/= <<"agent">>, R =/= <<"avatar">> ->
            Where("role must be \"agent\" or \"avatar\"");
        {[], #{<<"entity">> := E, <<"role">> := R}} ->
            Role = binary_to_existing_atom(R),
            case {maps:find(<<"credential">>, I), maps:find(<<"cert_sha256">>, I)} of
                {error, error} -> Where("credential or cert_sha256 required");
                {C, F} ->
                    case {cred_ok(C), F} of
                        {{error, Why}, _} -> Where(["credential ", Why]);
                        {ok, {ok, Fp}} when not is_binary(Fp) -> Where("cert_sha256 must be text");
                        {ok, _} ->
                            Id0 = #{entity => E, role => Role},
                            Id1 = case C of {ok, Cv} -> Id0#{credential => Cv}; error -> Id0 end,
                            Id2 = case F of {ok, Fv} -> Id1#{cert_sha256 => Fv}; error -> Id1 end,
                            identities(Rest, N + 1, [Id2 | Acc])
                    end
            end;
        {[], _} -> Where("entity and role required")
    end;
identities(_, N, _) ->
    {error, iolist_to_binary(io_lib:format("entry ~b: must be an object", [N]))}.

cred_ok(error) -> ok;
cred_ok({ok, C}) -> credential(C).

credential(C) when is_binary(C) ->
    case chars(C) of
        N when is_integer(N), N >= 8, N =< 1024 -> ok;
        _ -> credential(none)
    end;
credential(_) -> {error, <<"must be text of 8 to 1024 characters (there is no default credential)">>}.

%% evatar's verdict on the options as a whole, with the field it names.
bad_option({missing, Keys}) ->
    err(400, <<"bad_request">>, atom_to_binary(hd(Keys)),
        iolist_to_binary([lists:join(" and ", [atom_to_binary(K) || K <- Keys]),
                          " required (there are no default credentials), unless the pairing "
                          "lists identities"]));
bad_option({identities, duplicate_entity}) ->
    err(400, <<"bad_request">>, <<"identities">>, <<"an entity appears more than once">>);
bad_option({identity, _, {cert_sha256, _}}) ->
    err(400, <<"bad_request">>, <<"identities">>,
        <<"a cert_sha256 is not a SHA-256 fingerprint (64 hex digits, colons allowed)">>);
bad_option({K, _}) when is_atom(K) ->
    err(400, <<"bad_request">>, atom_to_binary(K),
        case maps:is_key(K, evatar:pairing_option_ranges()) of
            true -> range_message(K);
            false -> <<"not accepted by the pairing">>
        end);
bad_option(Bad) ->
    err(400, <<"bad_request">>, null,
        iolist_to_binary(io_lib:format("options not accepted: ~0tp", [Bad]))).

%% ---------------------------------------------------------------------------
%% MQTT Avatars
%% ---------------------------------------------------------------------------

%% @doc The MQTT Avatars this node keeps, with their state.
-spec mqtt_avatars() -> [map()].
mqtt_avatars() ->
    [keeper_status(S) || S <- mqtt_avatar:kept()].

keeper_status(#{entity_id := E, state := State, avatar := A, starts := St, crashes := C,
                next_delay_ms := D}) ->
    #{entity_id => E, state => State, running => is_pid(A), starts => St, crashes => C,
      next_delay_ms => D}.

%% @doc One kept MQTT Avatar: its state, its generated description (the
%% components as JSON and the BIL XML) and its problems.
-spec mqtt_avatar(binary()) -> {ok, map()} | {error, error()}.
mqtt_avatar(EntityId) ->
    with_avatar(EntityId,
                fun(Status, Pid) ->
                        D = mqtt_avatar:description(Pid),
                        #{components := Cs} = D,
                        Status#{components => [component(C) || C <- Cs],
                                description_xml => mqtt_avatar:description_xml(D),
                                problems => [problem(P) || P <- mqtt_avatar:problems(Pid)]}
                end).

%% @doc The problems an MQTT Avatar met (oldest first, at most 100).
-spec problems(binary()) -> {ok, [map()]} | {error, error()}.
problems(EntityId) ->
    with_avatar(EntityId, fun(_Status, Pid) -> [problem(P) || P <- mqtt_avatar:problems(Pid)] end).

problem(P) ->
    maps:map(fun(_, V) when is_binary(V); is_number(V); is_boolean(V); is_atom(V) -> V;
                (_, V) -> iolist_to_binary(io_lib:format("~0tp", [V]))
             end, P).

%% @doc Overrides an MQTT Avatar's generated description: `{"xml": BIL}'
%% replaces it with a hand-written one (mqtt_avatar's `description'), or
%% `{"overrides": {Device: {room, component, skip, parameters}}}' changes
%% how devices become components (docs/mqtt.md section 5). The Avatar
%% restarts with them and describes itself again.
-spec override_description(binary(), term()) -> {ok, map()} | {error, error()}.
override_description(EntityId, #{<<"xml">> := Xml} = B) when map_size(B) =:= 1 ->
    case is_binary(Xml) of
        true -> reconfigure(EntityId, #{description => Xml}, <<"xml">>);
        false -> err(400, <<"bad_request">>, <<"xml">>, <<"must be BIL XML text">>)
    end;
override_description(EntityId, #{<<"overrides">> := O} = B) when map_size(B) =:= 1 ->
    case overrides(O) of
        {ok, Overrides} -> reconfigure(EntityId, #{overrides => Overrides}, <<"overrides">>);
        {error, Why} -> err(400, <<"bad_request">>, <<"overrides">>, Why)
    end;
override_description(_EntityId, _) ->
    err(400, <<"bad_request">>, null, <<"the body must be {\"xml\": \"...\"} or {\"overrides\": {...}}">>).

reconfigure(EntityId, Changes, Field) ->
    case mqtt_avatar:reconfigure(EntityId, Changes) of
        ok -> {ok, #{entity_id => EntityId, restarted => true}};
        {error, not_found} ->
            err(404, <<"not_found">>, <<"entity_id">>, <<"no MQTT Avatar ", EntityId/binary, " on this node">>);
        {error, Problems} when is_list(Problems) ->
            err(400, <<"bad_request">>, Field,
                iolist_to_binary(lists:join("; ", [M || #{message := M} <- Problems])))
    end.

overrides(O) when is_map(O) ->
    Results = [{K, override(V)} || {K, V} <- maps:to_list(O)],
    case [{K, Why} || {K, {error, Why}} <- Results] of
        [] -> {ok, maps:from_list([{K, V} || {K, {ok, V}} <- Results])};
        [{K, Why} | _] -> {error, iolist_to_binary(["\"", K, "\": ", Why])}
    end;
overrides(_) ->
    {error, <<"must be an object keyed by device">>}.

override(V) when is_map(V) ->
    lists:foldl(fun(_, {error, _} = E) -> E;
                   ({K, X}, {ok, Acc}) ->
                        case {K, X} of
                            {<<"room">>, T} when is_binary(T) -> {ok, Acc#{room => T}};
                            {<<"component">>, T} when is_binary(T) -> {ok, Acc#{component => T}};
                            {<<"skip">>, T} when is_boolean(T) -> {ok, Acc#{skip => T}};
                            {<<"feedback">>, null} -> {ok, Acc#{feedback => none}};
                            {<<"feedback">>, T} when is_binary(T) -> {ok, Acc#{feedback => T}};
                            {<<"parameters">>, Ps} when is_map(Ps) ->
                                case lists:all(fun is_binary/1, maps:values(Ps)) of
                                    true -> {ok, Acc#{parameters => lists:sort(maps:to_list(Ps))}};
                                    false -> {error, <<"parameters: each value must be text">>}
                                end;
                            _ -> {error, iolist_to_binary(["bad key or value: ", K, " (known: room, "
                                                           "component, skip, feedback, parameters)"])}
                        end
                end, {ok, #{}}, maps:to_list(V));
override(_) ->
    {error, <<"must be an object">>}.

with_avatar(EntityId, Fun) ->
    with_kept(mqtt, EntityId, Fun).

%% ---------------------------------------------------------------------------
%% WoT Avatars (docs/wot.md section 6)
%% ---------------------------------------------------------------------------

%% @doc The WoT Avatars this node keeps, with their keeper's state.
-spec wot_avatars() -> [map()].
wot_avatars() ->
    [keeper_status(S) || S <- wot_avatar:kept()].

%% @doc The problems of a kept WoT Avatar: what its TD left out, then
%% (oldest first, at most 100) what went wrong while it ran.
-spec wot_problems(binary()) -> {ok, [map()]} | {error, error()}.
wot_problems(EntityId) ->
    with_kept(wot, EntityId, fun(_Status, Pid) -> [problem(P) || P <- wot_avatar:problems(Pid)] end).

%% A kept Avatar of either kind, running: Fun of its keeper's status and
%% its pid.
with_kept(Kind, EntityId, Fun) ->
    {Kept, Noun, List} = case Kind of
                             mqtt -> {mqtt_avatar:kept(), <<"MQTT Avatar">>, <<"/api/mqtt_avatars">>};
                             wot -> {wot_avatar:kept(), <<"WoT Avatar">>, <<"/api/wot_avatars">>}
                         end,
    case [S || #{entity_id := E} = S <- Kept, E =:= EntityId] of
        [#{avatar := Pid} = S] when is_pid(Pid) ->
            try
                {ok, Fun(keeper_status(S), Pid)}
            catch
                exit:_ -> err(503, <<"busy">>, null,
                              <<"the ", Noun/binary, " did not answer (restarting or busy); try again">>)
            end;
        [_] ->
            err(503, <<"not_running">>, null,
                <<"the ", Noun/binary, " is waiting to be restarted (GET ", List/binary, " says when)">>);
        [] ->
            err(404, <<"not_found">>, <<"entity_id">>,
                <<"no ", Noun/binary, " ", EntityId/binary, " on this node">>)
    end.

%% ---------------------------------------------------------------------------

not_found(Id) ->
    err(404, <<"not_found">>, <<"id">>, <<"no pairing ", Id/binary, " on this node">>).

busy(Id) ->
    err(503, <<"busy">>, null, <<"the pairing ", Id/binary, " did not answer in time; try again">>).

err(Status, Code, Field, Message) ->
    {error, #{status => Status, error => Code, field => Field, message => Message}}.

null_if_undefined(undefined) -> null;
null_if_undefined(V) -> V.
